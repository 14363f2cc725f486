"""ROS 2 bags (rosbag2 with MCAP storage): a rectified stereo pair's topics into a recording.

A ROS 2 stereo driver, or ``image_proc`` rectifying one, publishes each camera's rectified image
(``sensor_msgs/msg/Image`` or ``CompressedImage``) beside its ``sensor_msgs/msg/CameraInfo``. The
projection matrix P of a rectified pair holds everything the pipeline needs: fx, fy, cx, cy from
either camera, and the baseline from the right camera's ``P[0,3] = -fx * baseline`` (the ROS
convention). Left and right images are paired by their header stamps, which a synchronised
driver sets identically; an image without a partner within the tolerance is counted and left
out, never paired with the wrong frame.

Where the rig sits on the vehicle is not in the images: it is taken level and facing forward at
``camera_height`` metres above the road (the vehicle frame's origin lies on the road beneath the
left camera), with a pitch if the user gives one. A bag carries no ground truth, so ``evaluate``
reports only what needs none (timing, counts).

Stamps are read first, from the raw CDR bytes (a Header opens both image types), so frames are
paired and counted before any image is decoded; the second pass decodes only paired images.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from common.datasets.export import recording_info, write_frames
from common.errors import InputError
from common.geometry import camera_to_vehicle
from common.messages import Calibration, Message, StereoFrame

U8 = npt.NDArray[np.uint8]

IMAGE_TYPES: tuple[str, ...] = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
#: channels per raw encoding, and the OpenCV conversion to RGB (None: already RGB).
ENCODINGS: dict[str, tuple[int, int | None]] = {
    "rgb8": (3, None),
    "bgr8": (3, cv2.COLOR_BGR2RGB),
    "rgba8": (4, cv2.COLOR_RGBA2RGB),
    "bgra8": (4, cv2.COLOR_BGRA2RGB),
    "mono8": (1, cv2.COLOR_GRAY2RGB),
}
#: the recording keeps frames lossless, as the KITTI importers do.
IMAGE_FORMAT = "png"


def bag_files(path: Path) -> list[Path]:
    """The MCAP files of a bag: the file itself, or a rosbag2 folder's files in name order."""
    if path.is_file():
        return [path]
    if path.is_dir():
        files = sorted(path.glob("*.mcap"))
        if files:
            return files
        raise InputError(f"{path}: no .mcap files in this folder (only rosbag2's MCAP storage is read)")
    raise InputError(f"{path}: bag missing")


#: what the mcap reader raises on a damaged or cut file.
MCAP_ERRORS = (McapError, struct.error, ValueError, EOFError)


def _reader(stream: Any) -> Any:
    return make_reader(stream, decoder_factories=[DecoderFactory()])


def bag_topics(files: list[Path]) -> dict[str, str]:
    """Every topic of the bag with its message type."""
    out: dict[str, str] = {}
    for path in files:
        with open(path, "rb") as stream:
            try:
                summary = _reader(stream).get_summary()
            except MCAP_ERRORS as exc:
                raise InputError(f"{path}: not a readable MCAP file ({exc})") from None
            if summary is None:
                raise InputError(f"{path}: the MCAP file has no summary (was the recording cut short?)")
            for channel in summary.channels.values():
                schema = summary.schemas.get(channel.schema_id)
                out[channel.topic] = schema.name if schema is not None else ""
    return out


def _require(available: dict[str, str], topic: str, types: tuple[str, ...], role: str) -> None:
    if available.get(topic) in types:
        return
    listed = ", ".join(f"{t} ({available[t]})" for t in sorted(available) if available[t] in types) or "none"
    found = f"is a {available[topic]}" if topic in available else "is not in the bag"
    raise InputError(f"{role} topic {topic} {found}; the bag's {' / '.join(types)} topics: {listed}")


def header_stamp(data: bytes, topic: str) -> int:
    """Nanoseconds of the std_msgs/Header that opens a CDR-encoded image message."""
    if len(data) < 12:
        raise InputError(f"{topic}: a message of {len(data)} bytes is too short to hold a header")
    little = data[1] & 1  # CDR encapsulation: 0x0001 little-endian, 0x0000 big-endian
    sec, nanosec = struct.unpack_from("<iI" if little else ">iI", data, 4)
    return sec * 1_000_000_000 + nanosec


def _messages(files: list[Path], wanted: list[str], decode: bool) -> Iterator[tuple[str, Any]]:
    """(topic, message) in log-time order: the raw CDR bytes, or the decoded message with ``decode``."""
    for path in files:
        with open(path, "rb") as stream:
            reader = _reader(stream)
            try:
                if decode:
                    for _schema, channel, _message, decoded in reader.iter_decoded_messages(topics=wanted):
                        yield channel.topic, decoded
                else:
                    for _schema, channel, message in reader.iter_messages(topics=wanted):
                        yield channel.topic, message.data
            except MCAP_ERRORS as exc:
                raise InputError(f"{path}: unreadable MCAP data ({exc})") from None


def pair_stamps(left: list[int], right: list[int], tolerance_ns: int) -> list[tuple[int, int]]:
    """(left, right) stamps of the pairs: each left image with the nearest unused right one within
    the tolerance, in time order. Stamps need not arrive sorted; duplicates pair once."""
    lefts, rights = sorted(set(left)), sorted(set(right))
    pairs: list[tuple[int, int]] = []
    j = 0
    for stamp in lefts:
        while j < len(rights) and rights[j] < stamp - tolerance_ns:
            j += 1
        candidates = [k for k in (j, j + 1) if k < len(rights) and abs(rights[k] - stamp) <= tolerance_ns]
        if candidates:
            k = min(candidates, key=lambda i: abs(rights[i] - stamp))
            pairs.append((stamp, rights[k]))
            j = k + 1
    return pairs


@dataclass(frozen=True)
class CameraInfo:
    """What the pipeline takes from a sensor_msgs/CameraInfo: the rectified projection and size."""

    p: npt.NDArray[np.float64]  # 3x4
    width: int
    height: int


def camera_info(files: list[Path], topic: str) -> CameraInfo:
    """The topic's first CameraInfo (a rig's intrinsics do not change within a bag)."""
    for _topic, msg in _messages(files, [topic], decode=True):
        p = np.asarray(msg.p, dtype=np.float64).reshape(3, 4)
        return CameraInfo(p, int(msg.width), int(msg.height))
    raise InputError(f"{topic}: no CameraInfo message in the bag")


def calibration(left: CameraInfo, right: CameraInfo, camera_height: float, pitch_deg: float) -> Calibration:
    """The pair's Calibration from the two projection matrices (ROS: right P[0,3] = -fx * baseline)."""
    fx, fy, cx, cy = left.p[0, 0], left.p[1, 1], left.p[0, 2], left.p[1, 2]
    if not fx > 0.0:
        raise InputError(f"left CameraInfo has P[0,0] = {fx}: no projection matrix (is the camera calibrated?)")
    same = np.allclose(right.p[:, 0:3], left.p[:, 0:3], rtol=1e-3, atol=1e-3)
    if not same or (right.width, right.height) != (left.width, left.height):
        raise InputError("left and right CameraInfo differ in P's 3x3 part or size: the topics are not a "
                         "rectified pair (use the image_rect topics and their camera_info)")
    baseline = -right.p[0, 3] / right.p[0, 0]
    if not baseline > 0.0:
        raise InputError(f"right CameraInfo has P[0,3] = {right.p[0, 3]}: expected -fx * baseline < 0 "
                         "(are --left and --right swapped?)")
    return Calibration(fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy), baseline=float(baseline),
                       width=left.width, height=left.height,
                       cam_to_vehicle=camera_to_vehicle(camera_height, np.radians(pitch_deg)))


def to_rgb(msg: Any, topic: str) -> U8:
    """An Image or CompressedImage message as an 8-bit RGB array."""
    if hasattr(msg, "format"):  # sensor_msgs/CompressedImage
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), dtype=np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f"{topic}: a {msg.format!r} CompressedImage OpenCV cannot decode")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    encoding = str(msg.encoding).lower()
    if encoding not in ENCODINGS:
        raise InputError(f"{topic}: image encoding {msg.encoding!r} not supported (use one of {', '.join(ENCODINGS)})")
    channels, conversion = ENCODINGS[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if step < width * channels or data.size < step * height:
        raise InputError(f"{topic}: {data.size} bytes cannot hold a {width}x{height} {encoding} image of step {step}")
    rows = data[: step * height].reshape(height, step)[:, : width * channels]
    image = rows.reshape(height, width, channels)
    return np.ascontiguousarray(image if conversion is None else cv2.cvtColor(image, conversion))


@dataclass(frozen=True)
class Topics:
    """The four topics of a stereo pair."""

    left: str
    right: str
    left_info: str
    right_info: str

    @classmethod
    def of(cls, left: str, right: str, left_info: str | None, right_info: str | None) -> Topics:
        """Camera info beside each image topic by default (``.../left/image_rect`` -> ``.../left/camera_info``)."""
        return cls(left, right, left_info or sibling_info(left), right_info or sibling_info(right))


def sibling_info(image_topic: str) -> str:
    return image_topic.rsplit("/", 1)[0] + "/camera_info" if "/" in image_topic.strip("/") else "/camera_info"


def _frames(files: list[Path], names: Topics, pairs: list[tuple[int, int]], calib: Calibration
            ) -> Iterator[list[Message]]:
    """StereoFrames of the pairs in time order; only paired images are decoded, at most one pair ahead."""
    index_of = {stamp: i for i, (stamp, _) in enumerate(pairs)}
    right_of = {right: i for i, (_, right) in enumerate(pairs)}
    waiting: dict[int, dict[str, U8]] = {}
    next_index = 0
    for topic, msg in _messages(files, [names.left, names.right], decode=True):
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        table = index_of if topic == names.left else right_of
        i = table.get(stamp)
        if i is None or topic in waiting.get(i, {}):
            continue
        image = to_rgb(msg, topic)
        if (image.shape[1], image.shape[0]) != (calib.width, calib.height):
            raise InputError(f"{topic}: a {image.shape[1]}x{image.shape[0]} image, but its CameraInfo says "
                             f"{calib.width}x{calib.height}")
        waiting.setdefault(i, {})[topic] = image
        while next_index in waiting and len(waiting[next_index]) == 2:
            pair = waiting.pop(next_index)
            yield [StereoFrame(frame_id=next_index, stamp_ns=pairs[next_index][0], left=pair[names.left],
                               right=pair[names.right], calib=calib, image_format=IMAGE_FORMAT)]
            next_index += 1
        if next_index == len(pairs):
            return


def import_bag(bag: Path, names: Topics, out: Path, camera_height: float, pitch_deg: float = 0.0,
               tolerance_ms: float = 1.0, max_frames: int | None = None) -> tuple[int, int]:
    """Write the bag's stereo pairs to ``out``; returns (frames written, images left unpaired)."""
    if not camera_height > 0.0:
        raise InputError(f"--camera-height must be above 0 m, got {camera_height}")
    files = bag_files(bag)
    available = bag_topics(files)
    _require(available, names.left, IMAGE_TYPES, "left image")
    _require(available, names.right, IMAGE_TYPES, "right image")
    _require(available, names.left_info, (INFO_TYPE,), "left camera_info")
    _require(available, names.right_info, (INFO_TYPE,), "right camera_info")
    calib = calibration(camera_info(files, names.left_info), camera_info(files, names.right_info),
                        camera_height, pitch_deg)
    stamps: dict[str, list[int]] = {names.left: [], names.right: []}
    for topic, data in _messages(files, [names.left, names.right], decode=False):
        stamps[topic].append(header_stamp(data, topic))
    pairs = pair_stamps(stamps[names.left], stamps[names.right], round(tolerance_ms * 1e6))
    unpaired = len(stamps[names.left]) + len(stamps[names.right]) - 2 * len(pairs)
    if not pairs:
        raise InputError(f"{bag}: no {names.left} image has a {names.right} partner within {tolerance_ms} ms "
                         f"({len(stamps[names.left])} left, {len(stamps[names.right])} right images)")
    pairs = pairs[:max_frames]
    steps = np.diff([left for left, _ in pairs])
    rate = 1e9 / float(np.median(steps)) if len(steps) and np.median(steps) > 0 else 10.0
    info = recording_info("rosbag2", bag.stem, len(pairs), calib, volume=None, settings=None,
                          frame_rate_hz=rate, topics={"left": names.left, "right": names.right})
    written = write_frames(out, info, _frames(files, names, pairs, calib), f"import {bag.name}")
    return written, unpaired
