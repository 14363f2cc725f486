"""``stereovox evaluate RUN.mcap``: every figure of EVALUATION.md from one run recording.

The recording is self-contained (ground truth on ``groundtruth/*``, the pipeline's outputs on
their own keys, configuration and calibration in its metadata), so a run can be scored long after
it was made, on another computer. A figure whose input is missing is null with a one-line reason,
never a number made up from defaults.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from common.evaluation import latency, metrics
from common.evaluation.inputs import RunInputs, read_inputs
from common.evaluation.matching import FrameMatch, detection_in_vehicle, frame_match, truth_in_vehicle
from common.evaluation.odometry import odometry_errors
from common.evaluation.segmentation import segmentation_figures
from common.evaluation.velocity import fit_velocities
from common.geometry import invert
from common.messages import EgoMotion

F64 = npt.NDArray[np.float64]

#: every key of the JSON object, in EVALUATION.md's order.
KEYS: tuple[str, ...] = (
    "frames", "moving", "moving_tracks", "stationary_tracks", "id_switches", "speed", "stationary",
    "obstacles", "segmentation", "odometry", "stereo", "latency_ms", "throughput_hz",
)  # fmt: skip
OBSTACLE_KEYS: tuple[str, ...] = (
    "moving", "moving_tracks", "stationary_tracks", "id_switches", "speed", "stationary", "obstacles",
)  # fmt: skip


@dataclass
class Evaluation:
    """The JSON figures plus what the table and plots show beside them."""

    result: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    est_trajectory: list[F64] = field(default_factory=list)  # vehicle poses, world of frame 0
    true_trajectory: list[F64] = field(default_factory=list)
    tally: metrics.Tally = field(default_factory=metrics.Tally)  # the per-frame counts the figures come from
    stage_ms: dict[str, dict[int, float]] = field(default_factory=dict)
    frames: list[FrameMatch] = field(default_factory=list)  # truths and detections paired, per frame


def matched_frames(run: RunInputs) -> list[FrameMatch]:
    """Every frame with ground-truth objects, its truths and scored detections paired."""
    frames = []
    for fid in sorted(run.truth):
        true_pose = run.true_poses.get(fid, None if run.true_poses else np.eye(4))
        if true_pose is None:
            continue
        gt = run.truth[fid]
        truths = [truth_in_vehicle(obj, true_pose, run.volume) for obj in gt.objects]
        obstacles = run.obstacles.get(fid)
        detections = (
            []
            if obstacles is None
            else [
                detection_in_vehicle(o, np.asarray(obstacles.ego_pose), run.volume, run.calib, gt.dontcare)
                for o in obstacles.obstacles
                if o.state == "tracked"
            ]
        )
        frames.append(frame_match(fid, truths, detections))
    return frames


def stitched_poses(messages: list[EgoMotion]) -> list[F64]:
    """Estimated vehicle poses in one world: a re-anchored epoch is chained on with its ``delta``."""
    out: list[F64] = []
    anchor = np.eye(4)
    epoch: int | None = None
    for msg in messages:
        pose = np.asarray(msg.pose, dtype=np.float64)
        if epoch is not None and msg.world_epoch != epoch:
            anchor = out[-1] @ np.asarray(msg.delta, dtype=np.float64) @ invert(pose)
        epoch = msg.world_epoch
        out.append(anchor @ pose)
    return out


def odometry_figures(run: RunInputs, ev: Evaluation) -> dict[str, float] | None:
    """KITTI-style drift with poses in the left camera frame (T_cam = C^-1 T_vehicle C)."""
    fids = sorted(set(run.est_poses) & set(run.true_poses))
    if len(fids) < 2:
        ev.notes.append("odometry: needs odometry/ego and groundtruth/ego on 2+ common frames")
        return None
    est = stitched_poses([run.est_poses[f] for f in fids])
    truth = [run.true_poses[f] for f in fids]
    ev.est_trajectory = [invert(est[0]) @ p for p in est]
    ev.true_trajectory = [invert(truth[0]) @ p for p in truth]
    if run.calib is None:
        ev.notes.append("odometry: no calibration; compared in the vehicle frame (no lever arm)")
        c = np.eye(4)
    else:
        c = np.asarray(run.calib.cam_to_vehicle, dtype=np.float64)
    c_inv = invert(c)
    result = odometry_errors([c_inv @ p @ c for p in ev.est_trajectory], [c_inv @ p @ c for p in ev.true_trajectory])
    if result is None:
        ev.notes.append("odometry: the true path is shorter than the shortest segment (10 m)")
    return result


def stereo_figures(run: RunInputs, ev: Evaluation) -> dict[str, float | None] | None:
    """Mean over frames of each per-frame D1 figure (frames where it is defined)."""
    if not run.stereo:
        ev.notes.append("stereo: needs stereo_depth/disparity and groundtruth/disparity on common frames")
        return None
    out: dict[str, float | None] = {}
    for key in ("d1_all_pct", "d1_est_pct", "density_pct"):
        values = [f[key] for f in run.stereo.values() if f[key] is not None]
        out[key] = float(np.mean(values)) if values else None
    return out


def obstacle_figures(run: RunInputs, ev: Evaluation) -> dict[str, Any]:
    """Every figure of the tracker and the voxel clusters against the true objects."""
    out: dict[str, Any] = dict.fromkeys(OBSTACLE_KEYS)
    out["segmentation"] = None
    if not run.truth:
        ev.notes.append("obstacles, segmentation: no groundtruth/objects (no ground truth evaluates to nulls)")
        return out
    source = str(run.info.get("source", "synthetic"))
    if source != "synthetic":
        rate = float(run.info.get("frame_rate_hz", 10.0))
        refitted = fit_velocities(run.truth, rate)
        ev.notes.append(f"{source}: {refitted} true velocities refitted from positions over +-5 frames")
    frames = ev.frames = matched_frames(run)
    if not run.true_poses:
        ev.notes.append("no groundtruth/ego: ground-truth objects taken as already in the vehicle frame")
    if run.calib is None:
        ev.notes.append("no calibration: DontCare regions cannot be applied")
    if run.clusters:
        pairs = [(f.truths, run.clusters[f.frame_id]) for f in frames if f.frame_id in run.clusters]
        out["segmentation"] = segmentation_figures(pairs, run.gt_complete)
    else:
        ev.notes.append("segmentation: no voxel_mapper/clusters")
    if not run.obstacles:
        ev.notes.append("obstacles: no tracker/obstacles")
        return out
    tally = metrics.tally(frames)
    ev.tally = tally
    if tally.frames:
        out["moving"] = metrics.moving_figures(tally)
        out["speed"] = metrics.speed_figures(tally)
        out["stationary"] = metrics.stationary_figures(tally)
        if run.gt_complete:
            out["obstacles"] = metrics.obstacle_figures(tally)
        else:
            ev.notes.append("obstacles: ground truth does not list every structure (gt_complete false)")
    else:
        ev.notes.append(f"moving, speed, stationary: no frames after the {metrics.WARMUP_FRAMES}-frame warm-up")
    out["moving_tracks"] = metrics.moving_track_figures(frames)
    out["stationary_tracks"] = metrics.stationary_track_figures(frames)
    out["id_switches"] = metrics.id_switches(frames)
    if tally.frames and out["speed"] is None:
        ev.notes.append("speed: no true-positive moving pairs")
    if tally.frames and out["stationary"] is None:
        ev.notes.append("stationary: no counted stationary object after warm-up and grace")
    return out


def finite(value: Any) -> Any:
    """The figures with NaN and infinities as null, so the JSON stays standard JSON."""
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def evaluate_run(run: RunInputs) -> Evaluation:
    ev = Evaluation(result={})
    ev.notes.extend(run.notes)
    if run.decode_errors:
        ev.notes.append(f"{run.decode_errors} message(s) did not decode and were skipped")
    if run.truncated is not None:
        ev.notes.append(str(run.truncated))
    obstacles = obstacle_figures(run, ev)
    sink_trails = {f: list(o.timing) for f, o in run.obstacles.items()}
    ev.stage_ms = latency.stage_durations_ms(run.trails)
    result: dict[str, Any] = {"frames": len(run.frame_ids), **obstacles}
    result["odometry"] = odometry_figures(run, ev)
    result["stereo"] = stereo_figures(run, ev)
    result["latency_ms"] = latency.latency_ms(run.trails, sink_trails)
    result["throughput_hz"] = latency.throughput_hz(sink_trails)
    restarted = str(run.info.get("processed_by", ""))
    if "--from" in restarted and result["latency_ms"] is not None:
        # the stages before the restart ran when the run was first made, hours earlier perhaps:
        # their entries and the new ones on one trail measure the gap between the two, not latency
        result["latency_ms"]["end_to_end"] = {"p50": None, "p95": None}
        ev.notes.append(f"latency_ms.end_to_end: not measured on a run restarted by '{restarted}'")
    if result["latency_ms"] is None:
        ev.notes.append("latency_ms: no message carries a timing trail")
    if result["throughput_hz"] is None:
        ev.notes.append("throughput_hz: needs 2+ tracker outputs with a tracker timing entry")
    ev.result = {key: finite(result[key]) for key in KEYS}
    return ev


def evaluate_recording(path: str | Path, allow_truncated: bool = False) -> dict[str, Any]:
    """The JSON object of EVALUATION.md for one run recording."""
    return evaluate_run(read_inputs(path, allow_truncated)).result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, help="run recording (MCAP) with pipeline outputs and ground truth")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line of stdout")
    parser.add_argument("--plots", type=Path, metavar="DIR", help="write PNG plots into DIR")
    parser.add_argument(
        "--partial", action="store_true", help="score what a damaged recording holds instead of refusing it"
    )
    parser.add_argument(
        "--why",
        action="store_true",
        help="also print every scored truth-frame by outcome and clusters (to stderr with --json)",
    )


def run(args: argparse.Namespace) -> int:
    from common.evaluation.report import format_table

    run_inputs = read_inputs(args.recording, allow_truncated=args.partial)
    ev = evaluate_run(run_inputs)
    why = None
    if args.why or args.plots is not None:
        from common.evaluation.breakdown import breakdown

        why = breakdown(run_inputs, ev.frames)
    if args.plots is not None:
        from common.evaluation.plots import write_plots

        for written in write_plots(ev, args.plots, why):
            print(f"wrote {written}", file=sys.stderr)
    if args.json:
        for note in ev.notes:
            print(f"note: {note}", file=sys.stderr)
        print(json.dumps(ev.result))
    else:
        print(format_table(ev.result, ev.notes))
    if why is not None and args.why:
        from common.evaluation.breakdown import format_breakdown
        from common.evaluation.edges import format_edges

        out = sys.stderr if args.json else sys.stdout
        print(format_breakdown(why), file=out)
        print(format_edges(run_inputs.edges), file=out)
    return 0
