"""Numba's on-disk cache of the compiled kernels, one per version of the sources that hold kernels.

``numba.njit(cache=True)`` checks only the file a kernel is defined in. A kernel that calls one in
another file (corner_motion.py's ``_piece_velocities`` calls corner_lead.py's ``carry``) keeps
running the callee it was compiled with after that other file changes, without a word: session 67
measured a tracker change on such stale code before it noticed. So every kernel is cached under a
directory named by a digest of every file of ``common`` and ``services`` that uses numba; editing
any of them starts a fresh cache, and a restarted service still finds its kernels compiled.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES: tuple[str, ...] = ("common", "services")
#: another version's cache made this long ago is deleted when a new version's is first chosen: a
#: version's is several MB, and a service started before an edit may still be writing its own.
STALE_S: float = 86_400.0


def versioned_cache_dir(root: Path = ROOT) -> Path:
    """Where this version of the kernels is cached: under the checkout if it is writable (as an
    editable install's is), else under the user's cache."""
    digest = hashlib.sha256()
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            text = path.read_bytes()
            if b"numba" in text:
                digest.update(path.relative_to(root).as_posix().encode() + b"\0" + text)
    base = root / ".numba" if os.access(root, os.W_OK) else Path.home() / ".cache" / "stereovox" / "numba"
    return base / digest.hexdigest()[:16]


def use_versioned_cache() -> None:
    """Point numba's cache at ``versioned_cache_dir``, unless the environment already chose one."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    chosen = versioned_cache_dir()
    if not chosen.exists():
        prune(chosen)
    where = str(chosen)
    os.environ["NUMBA_CACHE_DIR"] = where  # read when numba is imported, here and in child processes
    if "numba" in sys.modules:  # imported already: its configuration has been read
        sys.modules["numba"].config.CACHE_DIR = where


def prune(keep: Path, stale_s: float = STALE_S) -> None:
    """Delete the other versions' caches beside ``keep`` made over ``stale_s`` ago (by the time their
    directory got its last package's subdirectory)."""
    if not keep.parent.is_dir():
        return
    now = time.time()
    for other in keep.parent.iterdir():
        try:
            if other != keep and other.is_dir() and now - other.stat().st_mtime > stale_s:
                shutil.rmtree(other, ignore_errors=True)
        except OSError:  # another process pruned it first
            continue
