"""Visual odometry error as KITTI's devkit measures it, with every start frame (step 1).

KITTI's ``evaluate_odometry.cpp`` compares relative poses over path segments of fixed true length
instead of absolute positions, so an early heading error is charged once per segment rather than
growing with the trajectory; that makes runs of different lengths comparable. EVALUATION.md keeps
the devkit's formulas but starts a segment at every frame (the devkit uses every tenth) because
our recordings are short.

Poses are 4x4 camera-to-world matrices in the camera frame of frame 0 (KITTI's ``poses/*.txt``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from common.errors import InputError

F64 = npt.NDArray[np.float64]

#: KITTI's segment lengths are 100..800 m; EVALUATION.md uses short ones that fit our recordings.
SEGMENT_LENGTHS: tuple[float, ...] = (10.0, 20.0, 50.0, 100.0)


def path_distances(poses: Sequence[F64]) -> F64:
    """Cumulative travelled distance at every frame (the devkit's ``trajectoryDistances``)."""
    positions = np.array([p[:3, 3] for p in poses], dtype=np.float64)
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def last_frame(distances: F64, first: int, length: float) -> int:
    """First frame whose path length from ``first`` exceeds ``length``; -1 if the run is too short."""
    beyond = np.nonzero(distances[first:] > distances[first] + length)[0]
    return int(first + beyond[0]) if beyond.size else -1


def rotation_error(error: F64) -> float:
    """Angle of the error rotation (radians), clipped as the devkit does."""
    d = 0.5 * (error[0, 0] + error[1, 1] + error[2, 2] - 1.0)
    return float(np.arccos(np.clip(d, -1.0, 1.0)))


def _relative(a: F64, b: F64) -> F64:
    return np.linalg.inv(a) @ b


def segment_errors(est: Sequence[F64], truth: Sequence[F64], lengths: Sequence[float]) -> list[tuple[float, float]]:
    """(translation error / L, rotation error / L) of every segment that fits, in devkit order."""
    distances = path_distances(truth)
    errors: list[tuple[float, float]] = []
    for first in range(len(truth)):
        for length in lengths:
            last = last_frame(distances, first, length)
            if last < 0:
                continue
            delta_truth = _relative(truth[first], truth[last])
            delta_est = _relative(est[first], est[last])
            error = np.linalg.inv(delta_est) @ delta_truth
            errors.append((float(np.linalg.norm(error[:3, 3])) / length, rotation_error(error) / length))
    return errors


def final_drift(est: Sequence[F64], truth: Sequence[F64]) -> float | None:
    """End-point error of the whole run relative to frame 0, as a share of the true path length."""
    length = float(path_distances(truth)[-1])
    if length <= 0.0:
        return None
    error = np.linalg.inv(_relative(est[0], est[-1])) @ _relative(truth[0], truth[-1])
    return float(np.linalg.norm(error[:3, 3])) / length


def odometry_errors(
    est: list[np.ndarray],
    truth: list[np.ndarray],
    lengths: Sequence[float] = SEGMENT_LENGTHS,
) -> dict[str, float] | None:
    """``t_err_pct``, ``r_err_deg_per_m``, ``final_drift_pct``; None when no segment fits.

    Means are over all segments of all lengths together (the devkit's overall figure), not a
    mean of per-length means.
    """
    if len(est) != len(truth):
        raise InputError(f"{len(est)} estimated poses for {len(truth)} true ones")
    if len(truth) < 2:
        return None
    est64 = [np.asarray(p, dtype=np.float64) for p in est]
    truth64 = [np.asarray(p, dtype=np.float64) for p in truth]
    errors = segment_errors(est64, truth64, lengths)
    drift = final_drift(est64, truth64)
    if not errors or drift is None:
        return None
    t_err = float(np.mean([e[0] for e in errors]))
    r_err = float(np.mean([e[1] for e in errors]))
    return {
        "t_err_pct": 100.0 * t_err,
        "r_err_deg_per_m": float(np.degrees(r_err)),
        "final_drift_pct": 100.0 * drift,
    }


def load_kitti_poses(path: str) -> list[F64]:
    """Poses from a KITTI ``poses/*.txt`` file: one 3x4 row-major [R|t] per line."""
    rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    if rows.shape[1] != 12:
        raise InputError(f"{path}: {rows.shape[1]} values per line, KITTI poses have 12")
    poses = []
    for row in rows:
        pose = np.eye(4)
        pose[:3, :] = row.reshape(3, 4)
        poses.append(pose)
    return poses
