"""``stereovox bench`` end to end on a short run: every figure the JSON line promises is there and plausible.

Times are never asserted (the machine is shared); what is asserted is that each figure was
actually measured: stages ran, the distributed graph delivered obstacles, every service's memory
was read, and the sweep covers the paper's five voxel edges at both image sizes.
"""

from __future__ import annotations

import json
import subprocess

import pytest
from conftest import REPO, stereovox_cmd

EDGES = [0.5, 0.25, 0.2, 0.15, 0.1]
STAGES = {"stereo_depth", "odometry", "voxel_mapper", "tracker"}


@pytest.mark.timeout(300)
def test_bench_json_has_every_figure() -> None:
    cmd = stereovox_cmd("bench", "--frames", "6", "--seconds", "6", "--kitti-frames", "4", "--json")
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=280)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert set(report["stages"]) == STAGES
    assert all(0 < s["p50_ms"] <= s["p95_ms"] for s in report["stages"].values())
    assert report["process_hz"] > 0
    assert report["first_obstacles_s"] > 0
    assert report["distributed_hz"] > 0, "no obstacles reached the recorder in the distributed run"
    assert 0 < report["e2e_ms"]["p50"] <= report["e2e_ms"]["p95"]
    assert set(report["dropped"]) == STAGES
    for figures in (report["rss_mb"], report["private_mb"], report["cpu_pct"]):
        assert set(figures) >= STAGES and all(v is not None and v > 0 for v in figures.values())
    assert all(report["private_mb"][n] < report["rss_mb"][n] for n in STAGES)  # a peak holds what is private now
    assert report["tracker_50"]["objects"] == 50 and report["tracker_50"]["cpu_ms"] > 0
    kitti = report["kitti_size"]
    assert set(kitti["stages"]) == STAGES and kitti["process_hz"] > 0
    for sweep in (report["voxel_sweep"], kitti["voxel_sweep"]):
        assert [row["edge_m"] for row in sweep] == EDGES
        assert all(row["ms"] > 0 and row["clusters"] >= 1 for row in sweep)
