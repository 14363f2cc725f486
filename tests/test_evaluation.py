"""`stereovox evaluate` on small hand-made run recordings whose every figure is known.

The scene: the vehicle drives along world x at 1 m a frame (10 Hz). Car A drives ahead at
1.5 m a frame (15 m/s), car B is parked 25 m ahead and 4 m to the left. A perfect pipeline
reports both where they are, with their true velocities, through the pose it estimated.
"""

from __future__ import annotations

import json
import subprocess
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, stereovox_cmd

from common.config import VolumeConfig
from common.evaluation.breakdown import Breakdown, breakdown, format_breakdown, missed_kind
from common.evaluation.evaluate import KEYS, evaluate_recording, matched_frames, stitched_poses
from common.evaluation.inputs import ClusterBox, FrameClusters, read_inputs
from common.evaluation.matching import DetectionView, TruthView, match, truth_in_vehicle
from common.evaluation.segmentation import clusters_in_vehicle, segmentation_figures, truths_share_volume
from common.evaluation.velocity import fit_velocities
from common.geometry import camera_to_vehicle, invert, make_pose
from common.messages import (
    Calibration,
    Cluster,
    Clusters,
    Disparity,
    EgoMotion,
    GroundTruthDisparity,
    GroundTruthEgo,
    GroundTruthObject,
    GroundTruthObjects,
    Obstacle,
    Obstacles,
    key_for,
)
from common.recording import RecordingWriter

CAM = camera_to_vehicle(1.5)
CALIB = {
    "fx": 500.0,
    "fy": 500.0,
    "cx": 320.0,
    "cy": 240.0,
    "baseline": 0.5,
    "width": 640,
    "height": 480,
    "cam_to_vehicle": CAM.tolist(),
}
CAR = np.array([4.0, 1.8, 1.5])


def car(oid: int, center: list[float], velocity: list[float], **visibility: float) -> GroundTruthObject:
    vis = visibility or {"visible_pixels": 2000, "visible_fraction": 1.0}
    speed = float(np.linalg.norm(velocity))
    return GroundTruthObject(
        id=oid,
        cls="car",
        center=np.array(center, float),
        size=CAR,
        yaw=0.0,
        velocity=np.array(velocity, float),
        moving=speed >= 1.0,
        **vis,
    )


def scene(k: int) -> list[GroundTruthObject]:
    return [car(1, [10.0 + 1.5 * k, 0.0, 0.75], [15.0, 0.0, 0.0]), car(2, [25.0, 4.0, 0.75], [0.0, 0.0, 0.0])]


def true_pose(k: int) -> np.ndarray:
    return make_pose(np.eye(3), [float(k), 0.0, 0.0])


Detect = Callable[[int, GroundTruthObject], Obstacle | None]


def perfect(k: int, obj: GroundTruthObject) -> Obstacle | None:
    speed = float(np.linalg.norm(obj.velocity))
    return obstacle(obj.id, obj.center, obj.velocity, moving=speed >= 1.0)


def obstacle(oid: int, centroid: np.ndarray, velocity: np.ndarray, moving: bool, state: str = "tracked") -> Obstacle:
    return Obstacle(
        id=oid,
        state=state,
        centroid=np.asarray(centroid, float),
        bbox_min=centroid - CAR / 2,
        bbox_max=centroid + CAR / 2,
        volume=10.0,
        velocity=np.asarray(velocity, float),
        velocity_rel=np.zeros(3),
        speed=float(np.linalg.norm(velocity)),
        moving=moving,
        position_cov=np.eye(3),
        velocity_cov=np.eye(3),
        age=5,
        color_rgb=np.zeros(3, np.float32),
    )


def write_run(
    path: Path,
    frames: int = 20,
    detect: Detect = perfect,
    objects: Callable[[int], list[GroundTruthObject]] = scene,
    est_pose: Callable[[int], np.ndarray] = true_pose,
    ground_truth: bool = True,
    extra: Callable[[int], list[Obstacle]] = lambda k: [],
    dontcare: np.ndarray | None = None,
    disparity: tuple[np.ndarray, np.ndarray] | None = None,
    clusters_on: Callable[[int, GroundTruthObject], int] = lambda k, obj: 1,
) -> Path:
    """A run recording: truth, estimated ego, clusters on the objects (``clusters_on`` each), obstacles and timings."""
    with RecordingWriter(path) as w:
        w.describe(
            {"volume": {"x_min": 0.0, "x_max": 28.7, "y_half": 8.2, "z_min": 0.0, "z_max": 3.5}},
            {"source": "synthetic", "gt_complete": True, "calib": CALIB},
        )
        for k in range(frames):
            stamp = int(1e9 + k * 1e8)
            t0 = int(5e9 + k * 1e8)
            trail = [
                ("camera_replay", t0, t0 + 1_000_000),
                ("stereo_depth", t0 + 1_000_000, t0 + 21_000_000),
                ("odometry", t0 + 21_000_000, t0 + 31_000_000),
                ("voxel_mapper", t0 + 31_000_000, t0 + 41_000_000),
                ("tracker", t0 + 41_000_000, t0 + 46_000_000),
            ]
            est = est_pose(k)
            # the pipeline sees the objects where they truly are relative to the vehicle, and
            # reports them in its own (estimated) world
            to_est_world = est @ invert(true_pose(k))
            objs = objects(k)
            obstacles = []
            clusters = []
            for obj in objs:
                c = to_est_world[:3, :3] @ obj.center + to_est_world[:3, 3]
                clusters.extend(
                    Cluster(
                        id=obj.id,
                        voxels=np.zeros((4, 3), np.int32),
                        voxel_count=4,
                        color_mean_rgb=np.zeros(3, np.float32),
                        color_var_rgb=np.zeros(3, np.float32),
                        color_mean_hsl=np.zeros(3, np.float32),
                        color_var_hsl=np.zeros(3, np.float32),
                        bbox_min=c - obj.size / 2 + 0.1,
                        bbox_max=c + obj.size / 2 - 0.1,
                        centroid=c + np.array([0.5 * piece, 0.0, 0.0]),
                        density=0.5,
                        volume=10.0,
                    )
                    for piece in range(clusters_on(k, obj))
                )
                det = detect(k, obj)
                if det is not None:
                    det.centroid = to_est_world[:3, :3] @ det.centroid + to_est_world[:3, 3]
                    det.velocity = to_est_world[:3, :3] @ det.velocity
                    obstacles.append(det)
            obstacles.extend(extra(k))
            if ground_truth:
                w.write(key_for("groundtruth/ego"), GroundTruthEgo(frame_id=k, stamp_ns=stamp, pose=true_pose(k)))
                gt = GroundTruthObjects(frame_id=k, stamp_ns=stamp, objects=objs, gt_complete=True)
                if dontcare is not None:
                    gt.dontcare = dontcare
                w.write(key_for("groundtruth/objects"), gt)
            w.write(
                key_for("odometry/ego"),
                EgoMotion(frame_id=k, stamp_ns=stamp, pose=est, valid=True, timing=trail[:1] + trail[2:3]),
            )
            w.write(
                key_for("voxel_mapper/clusters"),
                Clusters(
                    frame_id=k, stamp_ns=stamp, clusters=clusters, voxel_edge=0.25, ego_pose=est, timing=trail[:4]
                ),
            )
            if disparity is not None:
                w.write(
                    key_for("stereo_depth/disparity"),
                    Disparity(
                        frame_id=k,
                        stamp_ns=stamp,
                        disparity=disparity[0],
                        calib=Calibration(**{**CALIB, "cam_to_vehicle": CAM}),
                    ),
                )
                if ground_truth:
                    w.write(
                        key_for("groundtruth/disparity"),
                        GroundTruthDisparity(frame_id=k, stamp_ns=stamp, disparity=disparity[1]),
                    )
            w.write(
                key_for("tracker/obstacles"),
                Obstacles(frame_id=k, stamp_ns=stamp, obstacles=obstacles, ego_pose=est, timing=trail),
            )
    return path


def test_perfect_run(tmp_path: Path) -> None:
    r = evaluate_recording(write_run(tmp_path / "run.mcap"))
    assert r["frames"] == 20
    # frames 10..19 score; car A is moving and found in all of them
    assert r["moving"] == {
        "tp": 10,
        "fp": 0,
        "fn": 0,
        "tp_pct": 100.0,
        "fp_pct": 0.0,
        "fn_pct": 0.0,
        "precision": 1.0,
        "recall": 1.0,
    }
    assert r["moving_tracks"] == {"tracks": 1, "recall": 1.0, "median_latency_frames": 0.0}
    assert r["stationary_tracks"] == {"tracks": 1, "false_moving": 0}
    assert r["id_switches"] == 0
    assert r["speed"] == {"rmse_mps": 0.0, "median_mps": 0.0, "pairs": 10}
    assert r["stationary"] == {"recall": 1.0, "mislabelled_moving_pct": 0.0}
    assert r["obstacles"] == {"precision": 1.0, "phantoms_per_frame": 0.0}
    assert r["segmentation"] == {
        "one_cluster_pct": 100.0,
        "split_pct": 0.0,
        "missed_pct": 0.0,
        "merged_pct": 0.0,
        "phantom_clusters_per_frame": 0.0,
    }
    assert r["odometry"] is not None and r["odometry"]["t_err_pct"] == pytest.approx(0.0, abs=1e-9)
    assert r["stereo"] is None
    lat = r["latency_ms"]
    assert lat["stereo_depth"]["p50"] == pytest.approx(20.0)
    assert lat["tracker"]["p95"] == pytest.approx(5.0)
    assert lat["end_to_end"] == {"p50": pytest.approx(46.0), "p95": pytest.approx(46.0)}
    assert r["throughput_hz"] == pytest.approx(10.0)


def test_one_missed_object(tmp_path: Path) -> None:
    def miss_car_a(k: int, obj: GroundTruthObject) -> Obstacle | None:
        return None if obj.id == 1 else perfect(k, obj)

    r = evaluate_recording(write_run(tmp_path / "run.mcap", detect=miss_car_a))
    assert (r["moving"]["tp"], r["moving"]["fp"], r["moving"]["fn"]) == (0, 0, 10)
    assert r["moving"]["precision"] is None  # 0 / 0
    assert r["moving"]["recall"] == 0.0
    assert r["moving"]["fn_pct"] == 100.0
    assert r["moving_tracks"] == {"tracks": 1, "recall": 0.0, "median_latency_frames": None}
    assert r["speed"] is None
    assert r["stationary"] == {"recall": 1.0, "mislabelled_moving_pct": 0.0}


def test_one_false_moving_detection(tmp_path: Path) -> None:
    def parked_car_moves(k: int, obj: GroundTruthObject) -> Obstacle | None:
        if obj.id == 2:
            return obstacle(obj.id, obj.center, np.array([2.0, 0.0, 0.0]), moving=True)
        return perfect(k, obj)

    r = evaluate_recording(write_run(tmp_path / "run.mcap", detect=parked_car_moves))
    assert (r["moving"]["tp"], r["moving"]["fp"], r["moving"]["fn"]) == (10, 10, 0)
    assert r["moving"]["precision"] == 0.5
    assert r["moving"]["fp_pct"] == 50.0
    assert r["stationary"] == {"recall": 1.0, "mislabelled_moving_pct": 100.0}
    assert r["stationary_tracks"] == {"tracks": 1, "false_moving": 1}
    assert r["obstacles"]["precision"] == 1.0  # it is still a real obstacle


def test_detections_on_ignored_objects_count_nowhere(tmp_path: Path) -> None:
    def with_ignored(k: int) -> list[GroundTruthObject]:
        return [
            *scene(k),
            car(3, [k + 15.0, -4.0, 0.75], [0.6, 0.0, 0.0]),  # between the speed classes
            car(4, [k + 12.0, 6.0, 0.75], [5.0, 0.0, 0.0], visible_pixels=30, visible_fraction=0.9),  # too small
            car(5, [k + 12.0, 12.0, 0.75], [5.0, 0.0, 0.0]),  # outside the volume (|y| > 8.2)
        ]

    def everything_moves(k: int, obj: GroundTruthObject) -> Obstacle | None:
        return obstacle(obj.id, obj.center, obj.velocity, moving=True) if obj.id >= 3 else perfect(k, obj)

    r = evaluate_recording(write_run(tmp_path / "run.mcap", detect=everything_moves, objects=with_ignored))
    assert (r["moving"]["tp"], r["moving"]["fp"], r["moving"]["fn"]) == (10, 0, 0)
    assert r["obstacles"] == {"precision": 1.0, "phantoms_per_frame": 0.0}
    assert r["moving_tracks"]["tracks"] == 1


def test_phantom_and_unscored_states(tmp_path: Path) -> None:
    def extra(k: int) -> list[Obstacle]:
        return [
            obstacle(90, np.array([k + 8.0, -6.0, 0.5]), np.array([3.0, 0.0, 0.0]), moving=True),  # phantom
            obstacle(91, np.array([k + 9.0, -6.0, 0.5]), np.array([3.0, 0.0, 0.0]), True, state="acceptance"),
            obstacle(92, np.array([k + 9.0, -6.0, 0.5]), np.array([3.0, 0.0, 0.0]), True, state="ghost"),
        ]

    r = evaluate_recording(write_run(tmp_path / "run.mcap", extra=extra))
    assert (r["moving"]["tp"], r["moving"]["fp"], r["moving"]["fn"]) == (10, 10, 0)
    assert r["obstacles"] == {"precision": pytest.approx(2 / 3), "phantoms_per_frame": 1.0}


def test_dontcare_region_hides_a_detection(tmp_path: Path) -> None:
    def extra(k: int) -> list[Obstacle]:
        # 10 m ahead on the optical axis of a camera 1.5 m up: projects near the principal point
        return [obstacle(90, np.array([k + 10.0, 0.0, 1.5]), np.array([3.0, 0.0, 0.0]), moving=True)]

    def only_parked(k: int) -> list[GroundTruthObject]:
        return scene(k)[1:]

    box = np.array([[300.0, 220.0, 340.0, 260.0]], np.float32)
    hidden = evaluate_recording(write_run(tmp_path / "a.mcap", objects=only_parked, extra=extra, dontcare=box))
    shown = evaluate_recording(write_run(tmp_path / "b.mcap", objects=only_parked, extra=extra))
    assert hidden["moving"]["fp"] == 0
    assert shown["moving"]["fp"] == 10


def test_constant_velocity_error_gives_that_rmse(tmp_path: Path) -> None:
    def biased(k: int, obj: GroundTruthObject) -> Obstacle | None:
        det = perfect(k, obj)
        assert det is not None
        det.velocity = det.velocity + np.array([0.3, 0.4, 0.0])  # |error| = 0.5 m/s
        return det

    r = evaluate_recording(write_run(tmp_path / "run.mcap", detect=biased))
    assert r["speed"] == {"rmse_mps": pytest.approx(0.5), "median_mps": pytest.approx(0.5), "pairs": 10}


def test_id_switch_is_counted(tmp_path: Path) -> None:
    def renumbered(k: int, obj: GroundTruthObject) -> Obstacle | None:
        det = perfect(k, obj)
        if det is not None and obj.id == 1 and k >= 12:
            det.id = 77
        return det

    assert evaluate_recording(write_run(tmp_path / "run.mcap", detect=renumbered))["id_switches"] == 1


def test_odometry_drift_gives_known_t_err_and_leaves_detections_alone(tmp_path: Path) -> None:
    def drifting(k: int) -> np.ndarray:
        return make_pose(np.eye(3), [1.02 * k, 0.0, 0.0])

    r = evaluate_recording(write_run(tmp_path / "run.mcap", frames=31, est_pose=drifting))
    expected = (20 * 0.02 * 11 / 10 + 10 * 0.02 * 21 / 20) / 30
    assert r["odometry"]["t_err_pct"] == pytest.approx(100 * expected)
    assert r["odometry"]["final_drift_pct"] == pytest.approx(2.0)
    assert r["moving"]["fn"] == 0 and r["moving"]["fp"] == 0


def test_recording_without_ground_truth_evaluates_to_nulls(tmp_path: Path) -> None:
    path = write_run(tmp_path / "run.mcap", ground_truth=False)
    r = evaluate_recording(path)
    for key in (
        "moving",
        "moving_tracks",
        "stationary_tracks",
        "id_switches",
        "speed",
        "stationary",
        "obstacles",
        "segmentation",
        "odometry",
        "stereo",
    ):
        assert r[key] is None, key
    assert r["frames"] == 20 and r["throughput_hz"] == pytest.approx(10.0)
    out = subprocess.run(stereovox_cmd("evaluate", str(path)), cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "no ground truth evaluates to nulls" in out.stdout


def test_json_last_line_has_every_key_and_plots_are_written(tmp_path: Path) -> None:
    path = write_run(tmp_path / "run.mcap")
    plots = tmp_path / "plots"
    cmd = stereovox_cmd("evaluate", str(path), "--json", "--plots", str(plots), "--why")
    out = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert list(result) == list(KEYS)
    assert result["moving"]["tp"] == 10
    # the breakdown goes beside the JSON, never into stdout's last line
    assert "moving truth-frames by outcome and clusters (10 scored)" in out.stderr
    assert sorted(p.name for p in plots.iterdir()) == [
        "latency.png",
        "moving_outcomes.png",
        "speed_error.png",
        "trajectory.png",
    ]


def test_why_puts_every_scored_truth_frame_in_one_row(tmp_path: Path) -> None:
    """Car A is never tracked, parked car B is called moving: each in its row, adding up to the figures."""

    def miss_a_move_b(k: int, obj: GroundTruthObject) -> Obstacle | None:
        if obj.id == 1:
            return None
        return obstacle(obj.id, obj.center, np.array([2.0, 0.0, 0.0]), moving=True)

    path = write_run(tmp_path / "run.mcap", detect=miss_a_move_b)
    run = read_inputs(path)
    rows = breakdown(run, matched_frames(run))
    assert rows.moving == Counter({("car", "no track", "one"): 10})
    assert rows.stationary == Counter({("car", "wrong label", "one"): 10})
    figures = evaluate_recording(path)
    assert rows.total("moving") == figures["moving"]["tp"] + figures["moving"]["fn"]
    assert rows.total("moving", "found") == figures["moving"]["tp"] == 0

    perfect_run = read_inputs(write_run(tmp_path / "perfect.mcap"))
    found = breakdown(perfect_run, matched_frames(perfect_run))
    assert found.moving == Counter({("car", "found", "one"): 10})
    assert found.stationary == Counter({("car", "found", "one"): 10})


def test_why_counts_every_counted_object_frame_as_one_cluster_pct_does(tmp_path: Path) -> None:
    """Car 1 split in two in its last 5 frames, parked car 2 never clustered: rows by class and range."""

    def split_1_drop_2(k: int, obj: GroundTruthObject) -> int:
        return 0 if obj.id == 2 else 2 if k >= 15 else 1

    path = write_run(tmp_path / "run.mcap", clusters_on=split_1_drop_2)
    run = read_inputs(path)
    rows = breakdown(run, matched_frames(run)).segmentation
    # car 1 is 10 + 0.5 k m ahead: under 15 m up to frame 9; car 2, at (25 - k, 4), comes within
    # 22 m at frame 4 and within 15 m at frame 11
    assert rows == Counter({
        ("car", "< 15 m", "one"): 10, ("car", "15-22 m", "one"): 5, ("car", "15-22 m", "split"): 5,
        ("car", ">= 22 m", "missed"): 4, ("car", "15-22 m", "missed"): 7, ("car", "< 15 m", "missed"): 9,
    })  # fmt: skip
    one_pct = evaluate_recording(path)["segmentation"]["one_cluster_pct"]
    assert one_pct == pytest.approx(100.0 * 15 / 40)
    table = format_breakdown(breakdown(run, matched_frames(run)))
    assert "counted objects by clusters on them (40 object-frames, one cluster 37.5 %)" in table
    lines = table.splitlines()
    assert lines[lines.index(next(x for x in lines if x.startswith("counted objects"))) + 2].split() == [
        "car", "40", "37.5", "5", "20", "52.6", "29.4", "0.0"
    ]  # fmt: skip
    # car 2 had no cluster at all: all 20 of its frames are missed with nothing reaching it
    missed = lines.index(next(x for x in lines if x.startswith("missed objects")))
    assert lines[missed + 2].split() == ["car", "20", "0", "0", "20"]


def test_why_tells_the_speed_error_object_by_object(tmp_path: Path) -> None:
    """Two moving cars read 1.0 and 0.5 m/s off: each its row, worst first, adding up to the RMSE."""

    def two_movers(k: int) -> list[GroundTruthObject]:
        return [*scene(k), car(3, [8.0 + 1.0 * k, -4.0, 0.75], [10.0, 0.0, 0.0])]

    def off(k: int, obj: GroundTruthObject) -> Obstacle | None:
        det = perfect(k, obj)
        assert det is not None
        det.velocity = det.velocity + {1: np.array([0.3, 0.4, 0.0]), 3: np.array([0.0, 1.0, 0.0])}.get(obj.id, 0.0)
        return det

    path = write_run(tmp_path / "run.mcap", detect=off, objects=two_movers)
    run = read_inputs(path)
    why = breakdown(run, matched_frames(run))
    rows = why.speed
    assert sorted(rows) == [(1, "car"), (3, "car")]
    assert rows[(1, "car")] == pytest.approx([0.5] * 10)
    assert rows[(3, "car")] == pytest.approx([1.0] * 10)
    speed = evaluate_recording(path)["speed"]
    assert speed["pairs"] == 20
    assert speed["rmse_mps"] == pytest.approx(np.sqrt((10 * 0.25 + 10 * 1.0) / 20))
    lines = format_breakdown(why).splitlines()
    head = lines.index(next(x for x in lines if x.startswith("speed error by object")))
    assert "20 true moving frames, RMSE 0.79 m/s, squared error 12.5 m^2/s^2" in lines[head]
    assert lines[head + 2].split() == ["3", "car", "10", "10.00", "80.0", "1.00", "1.00"]
    assert lines[head + 3].split() == ["1", "car", "10", "2.50", "20.0", "0.50", "0.50"]


def test_why_lists_the_moving_objects_never_labelled_and_when_they_were_counted(tmp_path: Path) -> None:
    """Car 1 labelled; car 3 comes into the volume in the last two frames, car 4 leaves it after the
    first two, car 5 is in view in frames 5-14 only: each never labelled, told by where it was counted."""

    def four_movers(k: int) -> list[GroundTruthObject]:
        hidden = {"visible_pixels": 2000, "visible_fraction": 1.0 if 5 <= k <= 14 else 0.1}
        return [
            *scene(k),
            car(3, [136.0 - 5.0 * k, -4.0, 0.75], [-50.0, 0.0, 0.0]),  # 28.0 m ahead at frame 18, 34 at 17
            car(4, [26.0 + 3.0 * k, -4.0, 0.75], [30.0, 0.0, 0.0]),  # 26, 28, then 30 m ahead
            car(5, [15.0 + 1.0 * k, 7.0, 0.75], [10.0, 0.0, 0.0], **hidden),
        ]

    def label_only_1(k: int, obj: GroundTruthObject) -> Obstacle | None:
        if obj.id == 4:
            return None
        return obstacle(obj.id, obj.center, obj.velocity, moving=obj.id == 1)

    path = write_run(tmp_path / "run.mcap", detect=label_only_1, objects=four_movers)
    run = read_inputs(path)
    why = breakdown(run, matched_frames(run))
    assert why.moving_tracks == evaluate_recording(path)["moving_tracks"]["tracks"] == 4
    assert evaluate_recording(path)["moving_tracks"]["recall"] == pytest.approx(0.25)
    rows = {oid: (cls, t.counted, t.matched, where) for oid, cls, t, where in why.unlabelled}
    assert rows == {
        3: ("car", [18, 19], 2, "last frames"),
        4: ("car", [0, 1], 0, "first frames"),
        5: ("car", list(range(5, 15)), 10, "mid-run"),
    }
    lines = format_breakdown(why).splitlines()
    head = lines.index(next(x for x in lines if x.startswith("moving objects never labelled moving (3 of 4)")))
    assert lines[head + 2].split() == ["3", "car", "2", "18-19", "2", "last", "frames"]
    assert lines[head + 4].split() == ["5", "car", "10", "5-14", "10", "mid-run"]
    assert lines[head + 5].strip() == "2 of 3 counted only within 4 frames of the run's start or end"


@pytest.mark.parametrize("damage", ["truncated", "not_mcap"])
def test_corrupt_recording_exits_2_naming_the_file(tmp_path: Path, damage: str) -> None:
    path = write_run(tmp_path / "run.mcap")
    data = path.read_bytes()
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(data[: len(data) // 2] if damage == "truncated" else b"not a recording at all")
    out = subprocess.run(stereovox_cmd("evaluate", str(bad)), cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert str(bad) in out.stderr


def test_stereo_figures_are_the_mean_of_per_frame_d1(tmp_path: Path) -> None:
    truth = np.full((2, 8), 10.0, dtype=np.float32)
    truth[1, 7] = np.nan
    est = np.array([[10, np.nan, np.nan, 20, 20, np.nan, 10, np.nan], [np.nan] * 7 + [50]], dtype=np.float32)
    r = evaluate_recording(write_run(tmp_path / "run.mcap", frames=3, disparity=(est, truth)))
    # the hand-made pair of test_evaluation_stereo, identical in every frame
    assert r["stereo"] == {
        "d1_all_pct": pytest.approx(100 * 9 / 15),
        "d1_est_pct": pytest.approx(50.0),
        "density_pct": pytest.approx(100 * 4 / 15),
    }


def truth_view(oid: int, x: float, y: float) -> TruthView:
    return TruthView(oid, np.array([x, y, 0.75]), CAR, 0.0, np.zeros(3), counted=True, motion="stationary")


def cluster_at(low: list[float], high: list[float]) -> ClusterBox:
    lo, hi = np.array(low), np.array(high)
    return ClusterBox((lo + hi) / 2, lo, hi)


def test_segmentation_one_split_missed_merged_and_phantom() -> None:
    truths = [truth_view(1, 10.0, 0.0), truth_view(2, 10.0, 3.0), truth_view(3, 20.0, 0.0), truth_view(4, 20.0, 5.0)]
    boxes = [
        cluster_at([8.2, -0.8, 0.1], [9.8, 0.8, 1.4]),  # rear half of object 1
        cluster_at([10.2, -0.8, 0.1], [11.8, 0.8, 1.4]),  # front half of object 1: split
        cluster_at([18.2, -0.8, 0.1], [21.8, 5.8, 1.4]),  # one cluster over objects 3 and 4: merged
        cluster_at([14.0, -6.0, 0.5], [15.0, -5.0, 2.0]),  # on nothing: a phantom
    ]
    frame = FrameClusters(np.eye(4), boxes)
    result = segmentation_figures([(truths, frame)], gt_complete=True)
    # object 1 split in two, object 2 missed, 3 and 4: the merged cluster's centroid (20, 2.5)
    # falls in neither grown box, so both count as missed; that cluster is no phantom though
    assert result == {
        "one_cluster_pct": 0.0,
        "split_pct": 25.0,
        "missed_pct": 75.0,
        "merged_pct": pytest.approx(100 / 3),
        "phantom_clusters_per_frame": 1.0,
    }
    assert segmentation_figures([(truths, frame)], gt_complete=False)["phantom_clusters_per_frame"] is None


def test_a_missed_object_is_told_by_the_clusters_reaching_it() -> None:
    own, shared_a, shared_b, untouched = (
        truth_view(1, 10.0, 0.0), truth_view(2, 10.0, 3.0), truth_view(3, 10.0, 6.0), truth_view(4, 30.0, 0.0)
    )  # fmt: skip
    counted = [own, shared_a, shared_b, untouched]
    boxes = [
        # object 1's own cluster, its centroid pulled 1.5 m behind it by smear
        ClusterBox(np.array([13.5, 0.0, 0.75]), np.array([8.2, -0.8, 0.1]), np.array([15.0, 0.8, 1.4])),
        cluster_at([9.0, 2.5, 0.1], [11.0, 6.5, 1.4]),  # over objects 2 and 3, centred between them
    ]
    vehicle = clusters_in_vehicle(FrameClusters(np.eye(4), boxes))
    kinds = [missed_kind(t, vehicle, counted) for t in counted]
    assert kinds == ["own, off centre", "shared", "shared", "untouched"]
    table = format_breakdown(Breakdown(missed=Counter(("car", k) for k in kinds)))
    assert table.splitlines()[-1].split() == ["car", "4", "1", "2", "1"]


def test_objects_the_scene_put_inside_each_other_are_told_apart_from_neighbours() -> None:
    kiosk = TruthView(1, np.array([12.0, -5.5, 1.5]), np.array([3.7, 2.0, 2.8]), 0.3, np.zeros(3), True, "stationary")
    inside = truth_view(2, 11.0, -4.8)  # a car-sized box reaching into the kiosk (turned by 0.3 rad)
    beside = truth_view(3, 12.0, -3.0)  # its side (y -3.9) 0.1 m clear of the kiosk's corner (y -4.0)
    above = TruthView(4, np.array([12.0, -5.5, 3.5]), np.array([0.5, 0.5, 1.0]), 0.0, np.zeros(3), True, "stationary")
    assert truths_share_volume(kiosk, inside) and truths_share_volume(inside, kiosk)
    assert not truths_share_volume(kiosk, beside)
    assert not truths_share_volume(kiosk, above)  # over its roof (2.9 m), not in it
    rows = Counter({("stationary", "kiosk", "no track"): 3, ("moving", "cyclist", "found"): 1})
    table = format_breakdown(Breakdown(inside=rows)).splitlines()
    assert table[-2].split() == ["moving", "cyclist", "1", "0", "0"]
    assert table[-1].split() == ["stationary", "kiosk", "0", "0", "3"]


def test_kitti_visibility_rules() -> None:
    def kitti(truncated: float, occluded: int) -> bool:
        obj = car(1, [10.0, 0.0, 0.75], [0.0, 0.0, 0.0], truncated=truncated, occluded=occluded)
        return truth_in_vehicle(obj, np.eye(4), VolumeConfig()).counted

    assert kitti(0.0, 0) and kitti(0.0, 1) and kitti(-1.0, -1)
    assert not kitti(0.0, 2) and not kitti(0.3, 0)


def test_real_data_velocities_are_fitted_from_positions() -> None:
    rng = np.random.default_rng(1)
    truth = {}
    for k in range(20):
        jitter = rng.normal(0.0, 0.03, size=3)
        moving = car(1, [10.0 + 1.5 * k, 0.0, 0.75], [0.0, 0.0, 0.0])  # stored velocity wrong on purpose
        parked = car(2, list(np.array([25.0, 4.0, 0.75]) + jitter), [0.0, 0.0, 0.0])
        truth[k] = GroundTruthObjects(frame_id=k, stamp_ns=int(k * 1e8), objects=[moving, parked])
    assert fit_velocities(truth) == 40
    np.testing.assert_allclose(truth[0].objects[0].velocity, [15.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(truth[10].objects[0].velocity, [15.0, 0.0, 0.0], atol=1e-9)
    # jitter of 3 cm at 10 Hz would read up to ~0.6 m/s frame to frame; the fit stays stationary
    assert max(np.linalg.norm(truth[k].objects[1].velocity) for k in truth) < 0.3


def test_unmatched_detection_outside_the_volume_counts_nowhere(tmp_path: Path) -> None:
    def extra(k: int) -> list[Obstacle]:
        return [obstacle(90, np.array([k + 35.0, 0.0, 0.5]), np.array([3.0, 0.0, 0.0]), moving=True)]

    r = evaluate_recording(write_run(tmp_path / "run.mcap", extra=extra))
    assert r["moving"]["fp"] == 0
    assert r["obstacles"]["phantoms_per_frame"] == 0.0


def test_partial_scores_what_a_cut_recording_holds(tmp_path: Path) -> None:
    data = write_run(tmp_path / "run.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])
    cmd = stereovox_cmd("evaluate", str(cut), "--partial", "--json")
    out = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "ends early" in out.stderr and str(cut) in out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1])["frames"] > 0


def detection_view(oid: int, x: float, y: float, moving: bool = False) -> DetectionView:
    return DetectionView(oid, np.array([x, y, 0.7]), np.zeros(3), moving, ignored=False)


def test_matching_is_one_to_one_within_the_grown_box() -> None:
    truths = [truth_view(1, 10.0, 0.0), truth_view(2, 10.0, 2.4)]
    dets = [
        detection_view(10, 10.1, 1.25),  # inside both grown boxes, a little nearer object 2
        detection_view(11, 10.0, 2.6),  # object 2
        detection_view(12, 12.45, 0.0),  # within 0.5 m of object 1's front (x 12.0)
        detection_view(13, 12.6, 5.0),  # near nothing
    ]
    # the assignment keeps 11 on object 2 (it fits nowhere else) and gives 10 to object 1
    assert match(dets[:2], truths) == {0: 0, 1: 1}
    assert match(dets[2:], truths) == {0: 0}
    assert match([], truths) == {} and match(dets, []) == {}


def test_a_second_piece_of_an_object_is_no_phantom_but_a_moving_one_is_a_false_positive(tmp_path: Path) -> None:
    def pieces(k: int) -> list[Obstacle]:
        return [
            # world frame (the estimated pose is the true one here): the front of the parked car
            # and the rear of car A
            obstacle(80, np.array([26.5, 4.3, 0.5]), np.zeros(3), moving=False),
            obstacle(81, np.array([10.0 + 1.5 * k - 1.8, 0.2, 0.5]), np.array([15.0, 0, 0]), moving=True),
        ]

    r = evaluate_recording(write_run(tmp_path / "run.mcap", extra=pieces))
    assert r["obstacles"] == {"precision": 1.0, "phantoms_per_frame": 0.0}
    assert (r["moving"]["tp"], r["moving"]["fp"], r["moving"]["fn"]) == (10, 10, 0)
    assert r["speed"]["pairs"] == 10


def test_a_reanchored_odometry_epoch_is_chained_on_with_its_delta() -> None:
    step = make_pose(np.eye(3), [1.0, 0.0, 0.0])
    msgs = []
    for k in range(20):
        epoch, local = (0, k) if k < 10 else (1, k - 10)  # the world restarts at frame 10
        msgs.append(EgoMotion(frame_id=k, stamp_ns=k, pose=true_pose(local), delta=step, world_epoch=epoch))
    poses = stitched_poses(msgs)
    np.testing.assert_allclose([p[0, 3] for p in poses], np.arange(20.0), atol=1e-12)
