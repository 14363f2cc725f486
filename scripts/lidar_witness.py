"""The Velodyne's word on KITTI raw 0009's motion, to tell odometry error from error in the truth.

Issue 6 scores raw 0009 against the OXTS poses. Two independent visual odometries (stereovox and
VISO2-S, ``../shared/anchors``) agree on the camera's direction of travel to within 0.1 deg, and
the OXTS poses disagree with both by about 1.5 deg. A third witness settles which side is wrong:
the drive's three Velodyne scans (frames 0, 25, 50) registered to each other, a measurement that
shares nothing with the cameras or the OXTS unit but the mounting calibration.

For each pair of scans this prints the camera's relative motion by the lidar, the OXTS truth, the
run's odometry and VISO2-S: the direction of travel (yaw of the translation in the left camera
frame, + to the right), the length and the turn. Then the floor: the segment t_err of a trajectory
that moves exactly as the truth does but in the lidar's direction of travel. No odometry that
follows the images can score below it.

Registration is Open3D's point-to-plane ICP, a well-kept implementation; Open3D (about 400 MB)
is not a stereovox dependency, so install it beside the project to run this::

    .venv/bin/pip install open3d
    .venv/bin/stereovox import kitti-raw ../shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0009_sync \\
        --out /tmp/raw0009.mcap
    .venv/bin/stereovox process /tmp/raw0009.mcap --out /tmp/raw0009_run.mcap --no-frames
    .venv/bin/python scripts/lidar_witness.py /tmp/raw0009_run.mcap

ICP starts once from the truth's motion and once from the odometry's: both starts must reach the
same pose, or the registration is not trusted and the script says so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import numpy.typing as npt

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from common.datasets import kitti_calib, velodyne  # noqa: E402
from common.evaluation.evaluate import stitched_poses  # noqa: E402
from common.evaluation.inputs import read_inputs  # noqa: E402
from common.evaluation.odometry import odometry_errors  # noqa: E402
from common.geometry import invert  # noqa: E402

F64 = npt.NDArray[np.float64]

DATE = REPO.parent / "shared" / "data" / "kitti_raw" / "2011_09_26"
DRIVE = DATE / "2011_09_26_drive_0009_sync"
ANCHOR = REPO.parent / "shared" / "anchors" / "viso2_raw0009_poses.txt"
#: voxel size (m) of the down-sampled scans, and the ICP's shrinking correspondence distances (m).
VOXEL_M = 0.25
DISTANCES_M = (2.0, 1.0, 0.5, 0.3)
#: two ICP starts that end further apart than this (m, deg) leave the registration untrusted.
AGREE_M, AGREE_DEG = 0.02, 0.02


def scan_in_camera(frame: int, velo_to_cam: F64) -> object:
    """One scan as an Open3D cloud in the left colour camera's frame, 4-60 m, with normals."""
    import open3d as o3d

    points = velodyne.read_scan(DRIVE / "velodyne_points" / "data" / f"{frame:010d}.bin")[:, :3].astype(np.float64)
    distance = np.linalg.norm(points, axis=1)
    points = points[(distance > 4.0) & (distance < 60.0)] @ velo_to_cam[:3, :3].T + velo_to_cam[:3, 3]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(VOXEL_M)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=4 * VOXEL_M, max_nn=30))
    return cloud


def register(source: object, target: object, start: F64) -> F64:
    """The pose taking ``source`` points into ``target``'s frame: coarse to fine, robust to outliers."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    pose = start
    for distance in DISTANCES_M:
        method = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=distance / 2))
        criteria = reg.ICPConvergenceCriteria(max_iteration=60)
        pose = reg.registration_icp(source, target, distance, pose, method, criteria).transformation
    return np.asarray(pose)


def travel(motion: F64) -> tuple[float, float, float]:
    """Direction of travel (deg, + right), length (m) and turn (deg, + right) of a camera motion."""
    t = motion[:3, 3]
    return (
        float(np.degrees(np.arctan2(t[0], t[2]))),
        float(np.linalg.norm(t)),
        float(np.degrees(np.arctan2(motion[0, 2], motion[2, 2]))),
    )


def yaw_about_y(degrees: float) -> F64:
    a = np.radians(degrees)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])


def turned_travel(truth: list[F64], offsets_deg: list[float]) -> list[F64]:
    """The truth's trajectory with each step's translation turned by its offset: same path, other heading of travel."""
    out = [np.eye(4)]
    for i in range(len(truth) - 1):
        step = invert(truth[i]) @ truth[i + 1]
        step[:3, 3] = yaw_about_y(offsets_deg[i]) @ step[:3, 3]
        out.append(out[-1] @ step)
    return out


def camera_trajectories(run_path: Path) -> tuple[list[F64], list[F64]]:
    """Estimated and true camera poses (camera 0 -> camera i), as ``evaluate`` compares them."""
    run = read_inputs(run_path)
    fids = sorted(set(run.est_poses) & set(run.true_poses))
    if fids[:1] != [0] or run.calib is None:
        raise SystemExit(f"{run_path}: needs raw 0009's odometry and truth from frame 0, with calibration")
    est = stitched_poses([run.est_poses[f] for f in fids])
    truth = [run.true_poses[f] for f in fids]
    c = np.asarray(run.calib.cam_to_vehicle, dtype=np.float64)
    c_inv = invert(c)
    return (
        [c_inv @ invert(est[0]) @ p @ c for p in est],
        [c_inv @ invert(truth[0]) @ p @ c for p in truth],
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a `stereovox process` run of KITTI raw 0009 (frames 0-50)")
    args = parser.parse_args()
    est, truth = camera_trajectories(args.run)
    viso2 = [np.vstack([np.array(line.split(), float).reshape(3, 4), [0, 0, 0, 1]]) for line in ANCHOR.open()]
    velo_to_cam = kitti_calib.load_raw(DATE).velo_to_cam2()
    scans = {f: scan_in_camera(f, velo_to_cam) for f in (0, 25, 50)}
    offsets: dict[tuple[int, int], float] = {}
    print("camera motion between scans: travel direction deg (+ right), length m, turn deg (+ right)")
    for a, b in ((0, 25), (25, 50), (0, 50)):
        sources = (("OXTS truth", truth), ("stereovox", est), ("VISO2-S", viso2))
        motions = {name: invert(poses[a]) @ poses[b] for name, poses in sources}
        lidar = register(scans[b], scans[a], motions["OXTS truth"])
        other = register(scans[b], scans[a], motions["stereovox"])
        gap = invert(lidar) @ other
        agree = np.linalg.norm(gap[:3, 3]) < AGREE_M and abs(travel(gap)[2]) < AGREE_DEG
        print(f"frames {a}-{b}" + ("" if agree else "  (ICP starts disagree: not trusted)"))
        for name, motion in (("Velodyne ICP", lidar), *motions.items()):
            d, length, turn = travel(motion)
            print(f"  {name:13s} {d:+7.3f}  {length:7.3f}  {turn:+7.3f}")
        offsets[(a, b)] = travel(lidar)[0] - travel(motions["OXTS truth"])[0]
    steps = len(truth) - 1
    for label, per_step in (
        ("halves", [offsets[(0, 25)] if i < 25 else offsets[(25, 50)] for i in range(steps)]),
        ("whole run", [offsets[(0, 50)]] * steps),
    ):
        floor = odometry_errors(turned_travel(truth, per_step), truth)
        assert floor is not None
        print(f"floor, the truth travelling in the lidar's direction ({label}): t_err {floor['t_err_pct']:.2f} %")
    ours = odometry_errors(est, truth)
    assert ours is not None
    print(f"this run: t_err {ours['t_err_pct']:.2f} %  r_err {ours['r_err_deg_per_m']:.4f} deg/m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
