"""The tracker's time against an earlier revision's, frame by frame in one process.

The machines here are shared, and their speed swings by a factor of two within minutes: single
runs of the benchmark took 2.9 to 5.9 ms a frame for the same code in one session (docs/results/
tracking.md, "Session 30"). A speed-up is only seen when both codes run side by side. So the
revision's ``services/tracker`` is taken out of git into a temporary package (its imports of
``services.tracker`` pointed at that copy; ``common`` stays this tree's, so the revision must
speak today's messages and configuration), and both trackers process every frame in turn, the
order swapped from frame to frame. The figure is the median of the per-frame time ratios.
"""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from common.config import Config
from services.tracker.benchmark import scene
from services.tracker.core import Tracker

REPO = Path(__file__).resolve().parents[2]
PACKAGE = "stereovox_rev"
#: modules of ``common`` that hold the tracker's own compiled steps: taken from the revision too, so
#: that a change to them is timed (``common``'s other modules are messages and configuration).
KERNELS: tuple[str, ...] = ("corner_motion", "boosted_trees")


def revision_tracker(rev: str, into: Path) -> ModuleType:
    """``services/tracker`` and the ``KERNELS`` as of ``rev``, importable as ``stereovox_rev.tracker``
    and ``stereovox_rev.<kernel>``; its core module."""
    listing = subprocess.run(
        ["git", "-C", str(REPO), "ls-tree", "--name-only", f"{rev}:services/tracker"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if listing.returncode != 0:
        raise SystemExit(f"against: no services/tracker at {rev!r}: {listing.stderr.strip()}")
    target = into / PACKAGE / "tracker"
    target.mkdir(parents=True)
    (into / PACKAGE / "__init__.py").write_text("")
    for name in listing.stdout.split():
        if not name.endswith((".py", ".json")):  # the code and its data (a model's trees, motion_model.py)
            continue
        show = ["git", "-C", str(REPO), "show", f"{rev}:services/tracker/{name}"]
        source = subprocess.run(show, capture_output=True, text=True, check=True).stdout
        (target / name).write_text(_renamed(source) if name.endswith(".py") else source)
    for kernel in KERNELS:
        show = ["git", "-C", str(REPO), "show", f"{rev}:common/{kernel}.py"]
        got = subprocess.run(show, capture_output=True, text=True, check=False)
        if got.returncode == 0:
            (into / PACKAGE / f"{kernel}.py").write_text(_renamed(got.stdout))
    sys.path.insert(0, str(into))
    for loaded in [m for m in sys.modules if m == PACKAGE or m.startswith(PACKAGE + ".")]:
        del sys.modules[loaded]
    return importlib.import_module(f"{PACKAGE}.tracker.core")


def _renamed(source: str) -> str:
    """A revision's source importing the revision's tracker and kernels instead of this tree's."""
    source = re.sub(r"\bservices\.tracker\b", f"{PACKAGE}.tracker", source)
    return re.sub(rf"\bcommon\.({'|'.join(KERNELS)})\b", rf"{PACKAGE}.\1", source)


def compare(rev: str, objects: int = 50, frames: int = 100, repeats: int = 3) -> dict[str, Any]:
    """CPU ms per frame of this tree's tracker and ``rev``'s (medians, frames 10 on), their median ratio,
    and whether the two gave the same obstacles (centroids within 1e-9 m, the same moving flags)."""
    scenes = scene(frames, objects, seed=0)
    with tempfile.TemporaryDirectory(prefix="stereovox-against-") as tmp:
        old = revision_tracker(rev, Path(tmp))
        now_ms: list[float] = []
        rev_ms: list[float] = []
        same = True
        for _ in range(repeats):
            trackers = [Tracker.from_config(Config()), old.Tracker.from_config(Config())]
            for k, (clusters, ego) in enumerate(scenes):
                spent, outs = [0.0, 0.0], [None, None]
                for i in (0, 1) if k % 2 == 0 else (1, 0):
                    start = time.process_time()
                    outs[i] = trackers[i].process(clusters, ego)
                    spent[i] = time.process_time() - start
                if k >= 10:
                    now_ms.append(spent[0] * 1e3)
                    rev_ms.append(spent[1] * 1e3)
                same = same and _same(outs[0], outs[1])
        sys.path.remove(tmp)
    now, then = np.array(now_ms), np.array(rev_ms)
    return {
        "against": rev,
        "objects": objects,
        "cpu_ms": float(np.median(now)),
        "against_cpu_ms": float(np.median(then)),
        "ratio": float(np.median(now / np.maximum(then, 1e-9))),
        "same_output": same,
    }


def _same(a: Any, b: Any) -> bool:
    if len(a.obstacles) != len(b.obstacles):
        return False
    return all(
        x.id == y.id and x.moving == y.moving and np.allclose(x.centroid, y.centroid, rtol=0.0, atol=1e-9)
        for x, y in zip(a.obstacles, b.obstacles, strict=True)
    )
