"""Middlebury 2003 stereo scenes (cones, teddy): image pairs with dense true disparity.

Each scene folder holds ``im2.png`` (left), ``im6.png`` (right) and ``disp2.png``, the left
view's disparity times 4 with 0 for unknown. Every scene becomes one frame, so ``evaluate``
reports the stereo stage's D1 over them; there is no ego motion and there are no objects.

The datasets publish no calibration. A plausible one is chosen so the stereo stage's automatic
search range (fx * baseline / its 2 m minimum depth) covers the scenes' disparities: the
focal length of the later Middlebury sets at quarter size (3740 / 4 = 935 px), a 0.16 m
baseline and the principal point at the image centre. 935 * 0.16 / 2 = 75 px, beyond the
largest true disparity (about 55 px), so no configuration override is needed.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from common.datasets.export import recording_info, write_frames
from common.datasets.images import read_pair
from common.errors import InputError
from common.geometry import camera_to_vehicle
from common.messages import Calibration, GroundTruthDisparity, Message, StereoFrame

F32 = npt.NDArray[np.float32]

FOCAL_PX: float = 3740.0 / 4.0
BASELINE_M: float = 0.16
#: table-top scenes: the rig's height only places points, it is not scored.
CAMERA_HEIGHT_M: float = 1.0
#: disp2.png stores disparity x 4.
DISPARITY_SCALE: float = 4.0
FRAME_NS: int = 100_000_000
SCENE_FILES: tuple[str, ...] = ("im2.png", "im6.png", "disp2.png")


def scenes(folder: Path) -> list[Path]:
    """Scene folders (those holding im2, im6 and disp2), in name order; the folder itself if it is one."""
    if not folder.is_dir():
        raise InputError(f"{folder}: Middlebury folder missing")
    candidates = [folder] if (folder / "im2.png").is_file() else sorted(p for p in folder.iterdir() if p.is_dir())
    found = [p for p in candidates if (p / "im2.png").is_file()]
    if not found:
        raise InputError(f"{folder}: no scene folder with im2.png, im6.png and disp2.png")
    for scene in found:
        for name in SCENE_FILES:
            if not (scene / name).is_file():
                raise InputError(f"{scene / name}: missing")
    return found


def read_disparity(path: Path) -> F32:
    """Left-view true disparity in pixels; unknown (0) is NaN."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.ndim != 2:
        raise InputError(f"{path}: not a readable single-channel disparity image")
    disparity = raw.astype(np.float32) / np.float32(DISPARITY_SCALE)
    disparity[raw == 0] = np.nan
    return disparity


def calibration(width: int, height: int) -> Calibration:
    return Calibration(fx=FOCAL_PX, fy=FOCAL_PX, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, baseline=BASELINE_M,
                       width=width, height=height, cam_to_vehicle=camera_to_vehicle(CAMERA_HEIGHT_M))


def scene_messages(scene: Path, frame: int) -> list[Message]:
    left, right = read_pair(scene / "im2.png", scene / "im6.png")
    truth = read_disparity(scene / "disp2.png")
    if truth.shape != left.shape[:2]:
        raise InputError(f"{scene / 'disp2.png'} is {truth.shape[1]}x{truth.shape[0]}, im2.png is "
                         f"{left.shape[1]}x{left.shape[0]}")
    stamp = frame * FRAME_NS
    calib = calibration(left.shape[1], left.shape[0])
    return [StereoFrame(frame_id=frame, stamp_ns=stamp, left=left, right=right, calib=calib, image_format="png"),
            GroundTruthDisparity(frame_id=frame, stamp_ns=stamp, disparity=truth, sparse=False)]


def import_scenes(folder: Path, out: Path, max_frames: int | None = None) -> int:
    """Write every scene of ``folder`` as one frame each; returns the frames written."""
    found = scenes(folder)[:max_frames]
    first = scene_messages(found[0], 0)
    calib = first[0].calib  # type: ignore[attr-defined]
    info = recording_info("middlebury", ",".join(p.name for p in found), len(found), calib, volume=None, settings=None,
                          scenes=[p.name for p in found])
    frames = (first if k == 0 else scene_messages(scene, k) for k, scene in enumerate(found))
    return write_frames(out, info, frames, f"import middlebury {folder.name}")
