"""A KITTI stereo sequence ready to write: frames, capture times, calibration and true ego motion.

Raw drives, tracking and odometry sequences differ only in where these facts come from; once
gathered here, each frame becomes a StereoFrame (images read lazily, so memory stays at one
pair) followed by its ground truth.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from common.datasets.images import read_pair
from common.errors import InputError
from common.geometry import invert
from common.messages import Calibration, GroundTruthEgo, Message, StereoFrame, VehicleMotion

F64 = npt.NDArray[np.float64]

#: PNG keeps the recording lossless; KITTI frames re-encode at about 0.5 MB a pair.
IMAGE_FORMAT = "png"


@dataclass
class StereoSequence:
    """Everything per frame except the dataset-specific ground truth."""

    frames: list[int]
    stamps: list[int]
    pairs: list[tuple[Path, Path]]
    calib: Calibration
    poses: list[F64] | None = None  # vehicle -> world, frame 0 identity
    velocities: F64 | None = None  # world frame, m/s
    motion: F64 | None = None  # the INS's forward speed (m/s) and yaw rate (rad/s) per frame

    def __post_init__(self) -> None:
        if not (len(self.frames) == len(self.stamps) == len(self.pairs)):
            raise InputError(f"{len(self.frames)} frames, {len(self.stamps)} times, {len(self.pairs)} image pairs")
        if self.poses is not None and len(self.poses) != len(self.frames):
            raise InputError(f"{len(self.poses)} poses for {len(self.frames)} frames")
        if self.motion is not None and len(self.motion) != len(self.frames):
            raise InputError(f"{len(self.motion)} INS samples for {len(self.frames)} frames")

    def ego(self, index: int) -> GroundTruthEgo | None:
        if self.poses is None:
            return None
        velocity = np.zeros(3) if self.velocities is None else self.velocities[index]
        return GroundTruthEgo(frame_id=self.frames[index], stamp_ns=self.stamps[index],
                              pose=self.poses[index], velocity=velocity)

    def vehicle(self, index: int) -> VehicleMotion | None:
        if self.motion is None:
            return None
        speed, yaw_rate = (float(v) for v in self.motion[index])
        return VehicleMotion(
            frame_id=self.frames[index], stamp_ns=self.stamps[index], speed_mps=speed, yaw_rate_rps=yaw_rate,
            source="oxts",
        )

    def messages(self, truth: Callable[[int], Sequence[Message]] = lambda _: []) -> Iterator[list[Message]]:
        """Per frame: the INS sample, the stereo pair, the true ego pose, then ``truth(frame)``.

        The INS sample goes first, as a vehicle's sensors would have it by the time the frame is
        processed; the odometry pairs the two by frame id.
        """
        for index, (frame, stamp, (left_path, right_path)) in enumerate(
            zip(self.frames, self.stamps, self.pairs, strict=True)
        ):
            left, right = read_pair(left_path, right_path)
            if (left.shape[1], left.shape[0]) != (self.calib.width, self.calib.height):
                raise InputError(f"{left_path} is {left.shape[1]}x{left.shape[0]}, the sequence is "
                                 f"{self.calib.width}x{self.calib.height}")
            vehicle = self.vehicle(index)
            out: list[Message] = [] if vehicle is None else [vehicle]
            out.append(StereoFrame(frame_id=frame, stamp_ns=stamp, left=left, right=right,
                                   calib=self.calib, image_format=IMAGE_FORMAT))
            ego = self.ego(index)
            if ego is not None:
                out.append(ego)
            yield [*out, *truth(frame)]


def relative_to_first(poses: Sequence[F64]) -> list[F64]:
    """Poses re-anchored so the first is the identity."""
    first = invert(poses[0])
    return [first @ p for p in poses]


def frame_numbers(pairs: Sequence[tuple[Path, Path]]) -> list[int]:
    """Frame numbers from zero-padded image names (000042.png -> 42)."""
    try:
        return [int(left.stem) for left, _ in pairs]
    except ValueError:
        bad = next(left for left, _ in pairs if not left.stem.isdigit())
        raise InputError(f"{bad}: image name is not a frame number") from None


def finite_difference_velocities(poses: Sequence[F64], stamps: Sequence[int]) -> F64:
    """World-frame velocities from positions where a dataset has no velocity sensor."""
    positions = np.array([p[:3, 3] for p in poses])
    times = np.asarray(stamps, dtype=np.float64) / 1e9
    if len(positions) < 2:
        return np.zeros((len(positions), 3))
    return np.gradient(positions, times, axis=0)
