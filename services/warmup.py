"""A few made-up frames through a throwaway core before a service says it is alive.

The numba kernels are compiled once, at setup, into the source tree's cache; each process still
loads every one it calls the first time it calls it, and OpenCV sets itself up on its first pair.
Without this the first frames of a run paid for it: in a 20-frame `stereovox demo` the voxel
mapper took 258 ms and the tracker 191 ms on frame 0 (18-20 and 2-3 ms later), stereo 176 (130),
so the first obstacles came half a second late and the summary's p95 was the start-up's
(docs/results/reliability.md, session 63). The frames here are made up, small and fixed, and go through
the codec as a message off the bus would (its arrays read-only: numba compiles for that apart);
the core they go through is a second instance, so the service's own starts clean.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

from common.codec import decode, encode
from common.geometry import camera_to_vehicle
from common.messages import Calibration, EgoMotion, Message, PointCloud, StereoFrame

log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)

#: frames each core is given: the tracker's left-behind test looks three back, and the made-up cloud
#: loses a box after frame 2 (``box_clouds``).
FRAMES: int = 6
#: the made-up rig: the synthetic scenarios' (common/scenarios/render.py), smaller.
WIDTH, HEIGHT, FOCAL, BASELINE, CAMERA_HEIGHT = 320, 240, 300.0, 0.4, 1.5
#: the vehicle's made-up speed (m a frame): odometry and the map see motion.
STEP_M: float = 0.5
#: the made-up cloud's boxes: near corners (x, y; m) and colours.
BOXES: tuple[tuple[float, float], ...] = ((8.0, -2.0), (14.0, 3.0), (20.0, 0.0))
BOX_COLOURS: tuple[tuple[int, int, int], ...] = ((200, 40, 40), (40, 200, 40), (40, 40, 200))


def off_the_wire(msg: M) -> M:
    """``msg`` as a subscriber gets it."""
    decoded: M = decode(encode(msg), type(msg))
    return decoded


def rig() -> Calibration:
    return Calibration(
        fx=FOCAL, fy=FOCAL, cx=WIDTH / 2, cy=HEIGHT / 2, baseline=BASELINE, width=WIDTH, height=HEIGHT,
        cam_to_vehicle=camera_to_vehicle(CAMERA_HEIGHT),
    )  # fmt: skip


def stereo_frames(count: int = FRAMES) -> list[StereoFrame]:
    """A textured wall 12 m ahead with a box 6 m ahead before it, the vehicle nearing both."""
    calib = rig()
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, (HEIGHT, 2 * WIDTH, 3), dtype=np.uint8)
    cols = np.arange(WIDTH)
    frames = []
    for k in range(count):
        wall, box = FOCAL * BASELINE / (12.0 - STEP_M * k), FOCAL * BASELINE / (6.0 - STEP_M * k)
        disparity = np.full((HEIGHT, WIDTH), wall)
        disparity[HEIGHT // 3 : 2 * HEIGHT // 3, WIDTH // 3 : 2 * WIDTH // 3] = box
        left = texture[:, k : k + WIDTH]
        right = np.empty_like(left)
        for row in range(HEIGHT):  # each left pixel seen in the right image, shifted by its disparity
            source = np.clip(np.rint(cols + disparity[row]).astype(np.int64), 0, WIDTH - 1)
            right[row] = left[row, source]
        frames.append(off_the_wire(StereoFrame(frame_id=k, stamp_ns=k * 100_000_000, left=np.ascontiguousarray(left),
                                               right=right, calib=calib)))  # fmt: skip
    return frames


def stereo_inputs() -> list[tuple[StereoFrame]]:
    """The stereo stage's and odometry's inputs, frame by frame."""
    return [(frame,) for frame in stereo_frames()]


def ego_motions(count: int = FRAMES) -> list[EgoMotion]:
    """The vehicle driving ahead ``STEP_M`` a frame, as odometry would say."""
    out = []
    for k in range(count):
        pose, delta = np.eye(4), np.eye(4)
        pose[0, 3], delta[0, 3] = STEP_M * k, STEP_M if k else 0.0  # pose_k = pose_k-1 @ delta
        out.append(off_the_wire(EgoMotion(frame_id=k, stamp_ns=k * 100_000_000, pose=pose, delta=delta,
                                          inliers=100, inlier_ratio=0.9, valid=True, world_epoch=1)))  # fmt: skip
    return out


def box_clouds(count: int = FRAMES) -> list[PointCloud]:
    """The road and three coloured boxes on it 8-20 m ahead, in the vehicle frame of each frame; a
    block in two colours, one above the other (one object in two parts: the join model is asked),
    and the last box gone after frame 2 (its voxels are forgotten: the map is rehashed)."""
    rng = np.random.default_rng(1)
    road = np.column_stack([rng.uniform(3, 28, 20_000), rng.uniform(-8, 8, 20_000), rng.normal(0, 0.02, 20_000)])
    parts, colours = [road], [np.full((len(road), 3), 90)]
    for (x, y), colour in zip(BOXES, BOX_COLOURS, strict=True):
        parts.append(rng.uniform([x, y, 0.0], [x + 1.5, y + 1.0, 1.6], (4_000, 3)))
        colours.append(np.full((4_000, 3), colour))
    for low, high, colour in ((0.0, 1.0, (30, 30, 120)), (1.0, 2.0, (180, 60, 40))):
        parts.append(rng.uniform([11.0, 1.0, low], [12.0, 2.0, high], (3_000, 3)))
        colours.append(np.full((3_000, 3), colour))
    world = np.vstack(parts)
    colors = np.vstack(colours).astype(np.uint8)
    gone = np.zeros(len(world), dtype=bool)
    gone[len(road) + 2 * 4_000 : len(road) + 3 * 4_000] = True
    corners = world[len(road) :: 40]
    clouds = []
    for k in range(count):
        kept = ~gone if k > 2 else np.ones(len(world), dtype=bool)
        seen = (world[kept] - [STEP_M * k, 0.0, 0.0]).astype(np.float32)
        near = (corners - [STEP_M * k, 0.0, 0.0]).astype(np.float32)
        ids, std = np.arange(len(near), dtype=np.int64), np.full(len(near), 0.1, np.float32)
        cloud = PointCloud(frame_id=k, stamp_ns=k * 100_000_000, points=seen, colors=colors[kept], keypoint_ids=ids,
                           keypoints=near, keypoint_std=std, origin=np.array([0.0, 0.0, CAMERA_HEIGHT]))  # fmt: skip
        clouds.append(off_the_wire(cloud))
    return clouds


def clouds_and_motions(count: int = FRAMES) -> list[tuple[PointCloud, EgoMotion]]:
    """The voxel mapper's inputs, frame by frame."""
    return list(zip(box_clouds(count), ego_motions(count), strict=True))


def warm(
    name: str, core: Callable[[], Callable[..., object]], inputs: Callable[[], Sequence[Sequence[Message]]]
) -> float:
    """Each frame's ``inputs()`` (in the stage's order) through a new ``core()``; the seconds it took.

    A failure, in making either, is logged and the service starts anyway: its first frames are then
    slow, not lost.
    """
    start = time.perf_counter()
    try:
        process = core()
        for frame in inputs():
            process(*frame)
    except Exception:  # a warm-up must never keep a service from starting
        log.warning("%s: warm-up failed; its first frames will load the compiled code", name, exc_info=True)
    seconds = time.perf_counter() - start
    log.info("%s warmed in %.2f s", name, seconds)
    return seconds
