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
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES: tuple[str, ...] = ("common", "services")


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
    where = str(versioned_cache_dir())
    os.environ["NUMBA_CACHE_DIR"] = where  # read when numba is imported, here and in child processes
    if "numba" in sys.modules:  # imported already: its configuration has been read
        sys.modules["numba"].config.CACHE_DIR = where
