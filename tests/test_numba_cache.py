"""Numba's cache follows every file that holds kernels (common/numba_cache.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from common.numba_cache import ROOT, prune, versioned_cache_dir

CALLER = """import numba
from common.callee import step

@numba.njit(cache=True)
def run(x):
    return step(x) + 1
"""
CALLEE = """import numba

@numba.njit(cache=True)
def step(x):
    return x * {factor}
"""
#: the caller's kernel, run in a fresh interpreter over the tree ``root`` (its cache given in the environment)
RUN = """import sys
sys.path.insert(0, {root!r})
from common.caller import run
print(run(10))
"""


def _tree(root: Path, factor: int) -> None:
    (root / "common").mkdir(parents=True, exist_ok=True)
    (root / "common" / "__init__.py").write_text("")
    (root / "common" / "caller.py").write_text(CALLER)
    (root / "common" / "callee.py").write_text(CALLEE.format(factor=factor))


def _run(root: Path) -> int:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(versioned_cache_dir(root))}  # as common/numba_cache.py chooses it
    out = subprocess.run([sys.executable, "-c", RUN.format(root=str(root))], env=env, cwd=root, capture_output=True,
                         text=True, timeout=240)  # fmt: skip
    assert out.returncode == 0, out.stderr
    return int(out.stdout.split()[-1])


def test_the_digest_follows_files_with_kernels_only(tmp_path: Path) -> None:
    _tree(tmp_path, 2)
    (tmp_path / "services").mkdir()
    (tmp_path / "services" / "plain.py").write_text("X = 1\n")
    first = versioned_cache_dir(tmp_path)
    (tmp_path / "services" / "plain.py").write_text("X = 2\n")
    assert versioned_cache_dir(tmp_path) == first
    _tree(tmp_path, 3)
    assert versioned_cache_dir(tmp_path) != first
    assert versioned_cache_dir(tmp_path).parent == tmp_path / ".numba"


def test_other_versions_caches_are_pruned_once_stale(tmp_path: Path) -> None:
    keep, fresh, stale = tmp_path / "c", tmp_path / "b", tmp_path / "a"
    for d in (keep, fresh, stale):
        d.mkdir()
        (d / "kernel.nbi").write_text("x")
    os.utime(stale, (0, 0))
    prune(keep, stale_s=3600)
    assert keep.is_dir() and fresh.is_dir() and not stale.exists()


@pytest.mark.timeout(600)
def test_a_kernel_runs_the_edited_kernel_it_calls_in_another_file(tmp_path: Path) -> None:
    # numba's own cache checks only the caller's file, and would keep x * 2 after the callee changed
    _tree(tmp_path, 2)
    assert _run(tmp_path) == 21
    assert _run(tmp_path) == 21  # from the cache
    _tree(tmp_path, 3)
    assert _run(tmp_path) == 31


def test_every_service_imports_with_the_versioned_cache_unless_one_is_chosen(tmp_path: Path) -> None:
    code = "import services.tracker.core, numba; print(numba.config.CACHE_DIR)"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(versioned_cache_dir())
    chosen = str(tmp_path / "mine")
    out = subprocess.run([sys.executable, "-c", code], env={**env, "NUMBA_CACHE_DIR": chosen}, cwd=ROOT,
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.stdout.strip() == chosen
