"""Every message on the bus and in recordings, and the one msgpack codec for all of them.

A message is a keyword-only dataclass with a schema name and version (``stereovox.PointCloud/1``).
Arrays and images travel as :mod:`common.wire_arrays` packs them, within its limits; decoding
checks every field against the dataclass's type hints, so a hostile or corrupt payload fails with
:class:`DecodeError` instead of producing a wrongly typed or shaped value deep inside a stage.

The contract (ARCHITECTURE.md): ``frame_id`` is the capture sequence number and is monotonic,
``stamp_ns`` the capture time, and ``timing`` a trail of ``(stage, start_ns, end_ns)`` in wall
clock time that every stage extends; a stage joining two inputs carries the union of their trails.
"""

from __future__ import annotations

import dataclasses
import math
import time
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import msgpack
import numpy as np
import numpy.typing as npt

from common.errors import DecodeError
from common.message_checks import check_consistent, check_finite
from common.wire_arrays import (
    MAX_ARRAY_BYTES,
    pack_array,
    pack_image,
    unpack_array,
    unpack_image,
)

NDArray = npt.NDArray[Any]

Timing = tuple[str, int, int]


def array_field(dtype: str, shape: tuple[int | None, ...], default: Any = None) -> Any:
    """A dataclass field holding a numpy array of a fixed dtype and shape pattern (None = any)."""
    meta = {"dtype": dtype, "shape": shape}
    if default is None:
        return field(metadata=meta)
    return field(default_factory=default, metadata=meta)


def _eye4() -> NDArray:
    return np.eye(4, dtype=np.float64)


def _zeros(*shape: int, dtype: str = "float64") -> typing.Callable[[], NDArray]:
    return lambda: np.zeros(shape, dtype=dtype)


@dataclass(kw_only=True)
class Message:
    """Fields every message carries; subclasses set SCHEMA and VERSION."""

    SCHEMA: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1

    frame_id: int
    stamp_ns: int
    timing: list[Timing] = field(default_factory=list)

    @classmethod
    def schema_id(cls) -> str:
        return f"stereovox.{cls.SCHEMA}/{cls.VERSION}"


# ----------------------------------------------------------------------------- nested records


@dataclass(kw_only=True)
class Calibration:
    """Rectified pinhole stereo rig of the left camera, and where it sits on the vehicle.

    ``cam_to_vehicle`` maps left-camera coordinates (x right, y down, z forward) to the vehicle
    frame (x forward, y left, z up, origin on the road under the left camera).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    width: int
    height: int
    cam_to_vehicle: NDArray = array_field("float64", (4, 4), _eye4)


@dataclass(kw_only=True)
class Cluster:
    """One voxel cluster in the world frame (the paper's Sect. IV-B)."""

    id: int
    voxels: NDArray = array_field("int32", (None, 3))  # integer voxel coordinates
    voxel_count: int
    # this frame's stereo points in each voxel, in the order of ``voxels``; empty in recordings
    # made before it existed (the tracker then weighs every voxel alike)
    voxel_points: NDArray = array_field("int32", (None,), _zeros(0, dtype="int32"))
    color_mean_rgb: NDArray = array_field("float32", (3,))  # 0..1
    color_var_rgb: NDArray = array_field("float32", (3,))
    color_mean_hsl: NDArray = array_field("float32", (3,))  # 0..1
    color_var_hsl: NDArray = array_field("float32", (3,))
    bbox_min: NDArray = array_field("float64", (3,))
    bbox_max: NDArray = array_field("float64", (3,))
    centroid: NDArray = array_field("float64", (3,))
    density: float  # voxels / bounding-box volume in voxels
    volume: float  # m^3 occupied by the cluster's voxels


@dataclass(kw_only=True)
class Obstacle:
    """One track (Sect. IV-C); positions and velocities in the world frame unless named _rel."""

    id: int
    state: str  # "acceptance" | "tracked" | "ghost"
    centroid: NDArray = array_field("float64", (3,))
    bbox_min: NDArray = array_field("float64", (3,))
    bbox_max: NDArray = array_field("float64", (3,))
    volume: float
    velocity: NDArray = array_field("float64", (3,))  # absolute, world frame
    velocity_rel: NDArray = array_field("float64", (3,))  # relative to the vehicle, vehicle frame
    speed: float
    moving: bool
    position_cov: NDArray = array_field("float64", (3, 3))
    velocity_cov: NDArray = array_field("float64", (3, 3))
    age: int
    color_rgb: NDArray = array_field("float32", (3,))


@dataclass(kw_only=True)
class GroundTruthObject:
    """A true object; box centre is the geometric centre, in the world frame.

    Visibility follows the data's own convention: synthetic scenes fill ``visible_pixels`` and
    ``visible_fraction``; KITTI fills ``truncated`` and ``occluded`` (-1 = not known).
    """

    id: int
    cls: str
    center: NDArray = array_field("float64", (3,))
    size: NDArray = array_field("float64", (3,))  # length (along yaw), width, height
    yaw: float
    velocity: NDArray = array_field("float64", (3,))
    moving: bool
    visible_pixels: int = -1
    visible_fraction: float = -1.0
    truncated: float = -1.0
    occluded: int = -1


# ----------------------------------------------------------------------------- messages


@dataclass(kw_only=True)
class StereoFrame(Message):
    """A rectified colour stereo pair (RGB, HxWx3 uint8) with its calibration."""

    SCHEMA: ClassVar[str] = "StereoFrame"
    left: NDArray = array_field("uint8", (None, None, 3))
    right: NDArray = array_field("uint8", (None, None, 3))
    calib: Calibration
    image_format: str = "raw"  # how left/right travel: raw, png or jpeg


@dataclass(kw_only=True)
class PointCloud(Message):
    """Coloured 3D points in the vehicle frame of the frame they were seen in."""

    SCHEMA: ClassVar[str] = "PointCloud"
    points: NDArray = array_field("float32", (None, 3))
    colors: NDArray = array_field("uint8", (None, 3))


@dataclass(kw_only=True)
class Disparity(Message):
    """Left-image disparity in pixels; invalid = NaN. Always published: evaluation needs it."""

    SCHEMA: ClassVar[str] = "Disparity"
    disparity: NDArray = array_field("float32", (None, None))
    calib: Calibration


@dataclass(kw_only=True)
class EgoMotion(Message):
    """Vehicle pose in the world (vehicle frame at the first frame of the epoch) and its motion.

    ``delta`` is the previous vehicle frame expressed in the current one's terms as a pose:
    ``pose_k = pose_{k-1} @ delta``. ``world_epoch`` grows whenever the world is re-anchored.
    """

    SCHEMA: ClassVar[str] = "EgoMotion"
    pose: NDArray = array_field("float64", (4, 4), _eye4)
    delta: NDArray = array_field("float64", (4, 4), _eye4)
    inliers: int = 0
    inlier_ratio: float = 0.0
    valid: bool = False
    covariance: NDArray = array_field("float64", (6, 6), _zeros(6, 6))
    world_epoch: int = 0


@dataclass(kw_only=True)
class Clusters(Message):
    """Voxel clusters of one frame, world frame, with the egomotion they were mapped with."""

    SCHEMA: ClassVar[str] = "Clusters"
    clusters: list[Cluster] = field(default_factory=list)
    voxel_edge: float
    world_epoch: int = 0
    ego_pose: NDArray = array_field("float64", (4, 4), _eye4)
    voxel_count: int = 0  # voxels in the map this frame (clustered or not)


@dataclass(kw_only=True)
class Obstacles(Message):
    """Tracks of one frame; ``ego_pose`` is the estimated pose evaluation uses to compare."""

    SCHEMA: ClassVar[str] = "Obstacles"
    obstacles: list[Obstacle] = field(default_factory=list)
    world_epoch: int = 0
    ego_pose: NDArray = array_field("float64", (4, 4), _eye4)


@dataclass(kw_only=True)
class VehicleMotion(Message):
    """What the vehicle's own sensors (an INS, wheel speed and a gyro on the CAN bus) say of its motion.

    Body frame, sampled for one camera frame (same ``frame_id``): the twist part of what a ROS
    system publishes as ``nav_msgs/Odometry``. A sensor input, not ground truth, even where a
    dataset's truth comes from the same INS (KITTI's OXTS).
    """

    SCHEMA: ClassVar[str] = "VehicleMotion"
    speed_mps: float  # forward speed over ground
    yaw_rate_rps: float  # about the vehicle's up axis, counter-clockwise (left turn) positive
    source: str = ""  # which sensor, e.g. "oxts"


@dataclass(kw_only=True)
class GroundTruthEgo(Message):
    """True vehicle pose in the world frame (vehicle frame at the recording's first frame)."""

    SCHEMA: ClassVar[str] = "GroundTruthEgo"
    pose: NDArray = array_field("float64", (4, 4), _eye4)
    velocity: NDArray = array_field("float64", (3,), _zeros(3))  # world frame, m/s


@dataclass(kw_only=True)
class GroundTruthObjects(Message):
    """Every true object of one frame; ``dontcare`` holds ignored 2-D regions (x1, y1, x2, y2)."""

    SCHEMA: ClassVar[str] = "GroundTruthObjects"
    objects: list[GroundTruthObject] = field(default_factory=list)
    dontcare: NDArray = array_field("float32", (None, 4), _zeros(0, 4, dtype="float32"))
    gt_complete: bool = False


@dataclass(kw_only=True)
class GroundTruthDisparity(Message):
    """True left-image disparity, invalid = NaN; ``sparse`` for lidar-projected truth."""

    SCHEMA: ClassVar[str] = "GroundTruthDisparity"
    disparity: NDArray = array_field("float32", (None, None))
    sparse: bool = False


@dataclass(kw_only=True)
class Health(Message):
    """Once a second from every service: what it did and how fast."""

    SCHEMA: ClassVar[str] = "Health"
    service: str
    frames_in: int = 0
    frames_out: int = 0
    dropped: int = 0
    decode_errors: int = 0
    errors: int = 0
    p50_ms: float = 0.0
    p95_ms: float = 0.0
    uptime_s: float = 0.0
    detail: dict[str, Any] = field(default_factory=dict)


MESSAGE_TYPES: tuple[type[Message], ...] = (
    StereoFrame,
    PointCloud,
    Disparity,
    EgoMotion,
    Clusters,
    Obstacles,
    VehicleMotion,
    GroundTruthEgo,
    GroundTruthObjects,
    GroundTruthDisparity,
    Health,
)
SCHEMAS: dict[str, type[Message]] = {t.SCHEMA: t for t in MESSAGE_TYPES}

# ----------------------------------------------------------------------------- keys

#: topic (below ``stereovox/<vehicle>/``) -> message type carried there.
TOPICS: dict[str, type[Message]] = {
    "camera/stereo": StereoFrame,
    "stereo_depth/points": PointCloud,
    "stereo_depth/disparity": Disparity,
    "odometry/ego": EgoMotion,
    "voxel_mapper/clusters": Clusters,
    "tracker/obstacles": Obstacles,
    "vehicle/motion": VehicleMotion,
    "groundtruth/ego": GroundTruthEgo,
    "groundtruth/objects": GroundTruthObjects,
    "groundtruth/disparity": GroundTruthDisparity,
}
HEALTH_TOPIC_PREFIX = "health/"
DEFAULT_VEHICLE = "ego"


def key_for(topic: str, vehicle: str = DEFAULT_VEHICLE) -> str:
    """The Zenoh key expression of a topic on one vehicle."""
    return f"stereovox/{vehicle}/{topic}"


def topic_of(key: str) -> str:
    """The topic part of a key (``stereovox/ego/odometry/ego`` -> ``odometry/ego``)."""
    parts = key.split("/", 2)
    if len(parts) < 3 or parts[0] != "stereovox":
        return key
    return parts[2]


# ----------------------------------------------------------------------------- timing


def now_ns() -> int:
    """Wall-clock nanoseconds: comparable between processes (and computers sharing a clock)."""
    return time.time_ns()


def merged_trail(*inputs: Message) -> list[Timing]:
    """Union of the inputs' timing trails, in time order, each (stage, start) once."""
    seen: dict[tuple[str, int], Timing] = {}
    for msg in inputs:
        for stage, start, end in msg.timing:
            seen.setdefault((stage, int(start)), (stage, int(start), int(end)))
    return sorted(seen.values(), key=lambda t: (t[1], t[2]))


M = TypeVar("M", bound=Message)


def stamp_output(out: M, inputs: typing.Sequence[Message], stage: str, start_ns: int) -> M:
    """Give a stage's output the frame id and capture stamp of its inputs and extend the trail."""
    first = inputs[0]
    out.frame_id = first.frame_id
    out.stamp_ns = first.stamp_ns
    out.timing = [*merged_trail(*inputs), (stage, start_ns, now_ns())]
    return out


# ----------------------------------------------------------------------------- codec


def _to_wire(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out: dict[str, Any] = {}
        fmt = getattr(obj, "image_format", "raw")
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if "dtype" in f.metadata and isinstance(obj, StereoFrame) and f.name in ("left", "right"):
                out[f.name] = pack_image(value, fmt)
            else:
                out[f.name] = _to_wire(value)
        return out
    if isinstance(obj, np.ndarray):
        return pack_array(obj)
    if isinstance(obj, (list, tuple)):
        return [_to_wire(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): _to_wire(v) for k, v in obj.items()}
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def encode(msg: Message) -> bytes:
    """Serialise a message: ``{"schema": "PointCloud", "v": 1, "body": {...}}`` in msgpack."""
    body = _to_wire(msg)
    return msgpack.packb({"schema": msg.SCHEMA, "v": msg.VERSION, "body": body}, use_bin_type=True)


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _check_scalar(value: Any, hint: Any, where: str) -> Any:
    if hint is bool:
        if not isinstance(value, bool):
            raise DecodeError(f"{where}: expected bool, got {type(value).__name__}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise DecodeError(f"{where}: expected int, got {type(value).__name__}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise DecodeError(f"{where}: expected float, got {type(value).__name__}")
        if not math.isfinite(value):
            raise DecodeError(f"{where}: {value} is not a finite number")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise DecodeError(f"{where}: expected str, got {type(value).__name__}")
        return value
    return _MISSING


_MISSING = object()

def _from_wire(cls: type, value: Any, where: str) -> Any:
    if not isinstance(value, dict):
        raise DecodeError(f"{where}: expected a map for {cls.__name__}, got {type(value).__name__}")
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name not in value:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise DecodeError(f"{where}.{f.name}: missing")
            continue
        raw = value[f.name]
        sub = f"{where}.{f.name}"
        if "dtype" in f.metadata:
            if cls is StereoFrame and f.name in ("left", "right"):
                kwargs[f.name] = unpack_image(raw, sub)
            else:
                kwargs[f.name] = unpack_array(raw, sub, f.metadata["dtype"], f.metadata["shape"])
                check_finite(kwargs[f.name], f.name, sub)
            continue
        kwargs[f.name] = _convert(hints[f.name], raw, sub)
    return cls(**kwargs)


def _convert(hint: Any, raw: Any, where: str) -> Any:
    scalar = _check_scalar(raw, hint, where)
    if scalar is not _MISSING:
        return scalar
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if dataclasses.is_dataclass(hint):
        return _from_wire(hint, raw, where)
    if origin is list:
        if not isinstance(raw, list):
            raise DecodeError(f"{where}: expected a list, got {type(raw).__name__}")
        return [_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(raw)]
    if origin is tuple:
        if not isinstance(raw, list) or len(raw) != len(args):
            raise DecodeError(f"{where}: expected a {len(args)}-tuple")
        return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, raw, strict=True)))
    if origin is dict:
        if not isinstance(raw, dict) or not all(isinstance(k, str) for k in raw):
            raise DecodeError(f"{where}: expected a map with string keys")
        return raw
    if hint is Timing or hint == tuple[str, int, int]:
        return _convert(tuple[str, int, int], raw, where)
    raise DecodeError(f"{where}: cannot decode type {hint!r}")


def decode(data: bytes | bytearray | memoryview, expected: type[M] | None = None) -> M:
    """Parse bytes into a message; anything malformed raises :class:`DecodeError` only."""
    try:
        envelope = msgpack.unpackb(bytes(data), raw=False, strict_map_key=True, max_bin_len=MAX_ARRAY_BYTES)
    except DecodeError:
        raise
    except Exception as exc:  # msgpack raises a zoo of types on bad bytes
        raise DecodeError(f"not a msgpack message: {type(exc).__name__}: {exc}") from None
    if not isinstance(envelope, dict):
        raise DecodeError(f"envelope is {type(envelope).__name__}, not a map")
    schema, version, body = envelope.get("schema"), envelope.get("v"), envelope.get("body")
    cls = SCHEMAS.get(schema) if isinstance(schema, str) else None
    if cls is None:
        raise DecodeError(f"unknown schema {schema!r}; known: {sorted(SCHEMAS)}")
    if isinstance(version, bool) or version != cls.VERSION:
        raise DecodeError(f"{schema} version {version!r}, this build reads version {cls.VERSION}")
    if expected is not None and cls is not expected:
        raise DecodeError(f"got {schema} where {expected.SCHEMA} was expected")
    try:
        msg = _from_wire(cls, body, schema)
        check_consistent(msg, schema)
    except DecodeError:
        raise
    except Exception as exc:  # a value the dataclass or numpy refuses
        raise DecodeError(f"{schema}: {type(exc).__name__}: {exc}") from None
    return typing.cast(M, msg)
