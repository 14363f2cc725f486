"""Every message on the bus and in recordings, and the one msgpack codec for all of them.

A message is a keyword-only dataclass with a schema name and version (``stereovox.PointCloud/1``).
numpy arrays travel as ``{dtype, shape, bytes}`` with a dtype whitelist and size limits, so a
hostile or corrupt payload fails with :class:`DecodeError` instead of allocating gigabytes or
producing a wrongly shaped array deep inside a stage.

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

import cv2
import msgpack
import numpy as np
import numpy.typing as npt

from common.errors import DecodeError

NDArray = npt.NDArray[Any]

#: dtypes an array may have on the wire; anything else is refused.
DTYPES: frozenset[str] = frozenset(
    {"uint8", "uint16", "int16", "int32", "int64", "float32", "float64", "bool"}
)
#: largest single array accepted (bytes): a 4K RGB image is 25 MB, a 1M-point cloud 12 MB.
MAX_ARRAY_BYTES: int = 64 * 1024 * 1024
#: largest number of dimensions an array may declare.
MAX_NDIM: int = 4
#: image encodings a StereoFrame may travel with.
IMAGE_FORMATS: tuple[str, ...] = ("raw", "png", "jpeg")

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

_ND = "__nd__"
_IMG = "__img__"


def _pack_array(arr: NDArray) -> dict[str, Any]:
    arr = np.ascontiguousarray(arr)
    if arr.dtype.name not in DTYPES:
        raise DecodeError(f"dtype {arr.dtype.name} cannot be sent; allowed: {sorted(DTYPES)}")
    # a flat byte view: memoryview.cast refuses arrays with a zero in their shape (an empty cloud)
    data = memoryview(arr.reshape(-1).view(np.uint8))
    return {_ND: True, "dtype": arr.dtype.name, "shape": list(arr.shape), "data": data}


def _pack_image(arr: NDArray, fmt: str) -> Any:
    if fmt == "raw":
        return _pack_array(arr)
    if fmt not in IMAGE_FORMATS:
        raise DecodeError(f"image format {fmt!r} unknown; allowed: {IMAGE_FORMATS}")
    ext = ".png" if fmt == "png" else ".jpg"
    ok, buf = cv2.imencode(ext, cv2.cvtColor(np.ascontiguousarray(arr), cv2.COLOR_RGB2BGR))
    if not ok:
        raise DecodeError(f"could not encode image as {fmt}")
    return {_IMG: fmt, "data": buf.tobytes()}


def _to_wire(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out: dict[str, Any] = {}
        fmt = getattr(obj, "image_format", "raw")
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if "dtype" in f.metadata and isinstance(obj, StereoFrame) and f.name in ("left", "right"):
                out[f.name] = _pack_image(value, fmt)
            else:
                out[f.name] = _to_wire(value)
        return out
    if isinstance(obj, np.ndarray):
        return _pack_array(obj)
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


def _unpack_array(value: Any, where: str, dtype: str | None, shape: tuple[int | None, ...] | None) -> NDArray:
    if not isinstance(value, dict) or not value.get(_ND):
        raise DecodeError(f"{where}: expected an array, got {type(value).__name__}")
    name, dims, data = value.get("dtype"), value.get("shape"), value.get("data")
    if name not in DTYPES:
        raise DecodeError(f"{where}: dtype {name!r} not allowed")
    if dtype is not None and name != dtype:
        raise DecodeError(f"{where}: dtype {name} where {dtype} is required")
    if not isinstance(dims, list) or len(dims) > MAX_NDIM or not all(
        isinstance(d, int) and not isinstance(d, bool) and 0 <= d <= MAX_ARRAY_BYTES for d in dims
    ):
        raise DecodeError(f"{where}: shape {dims!r} is not a list of at most {MAX_NDIM} sizes")
    if shape is not None and (
        len(dims) != len(shape) or any(s is not None and s != d for s, d in zip(shape, dims, strict=False))
    ):
        raise DecodeError(f"{where}: shape {tuple(dims)} does not fit {shape}")
    if not isinstance(data, (bytes, bytearray)):
        raise DecodeError(f"{where}: array data is {type(data).__name__}, not bytes")
    itemsize = np.dtype(name).itemsize
    expected = math.prod(dims) * itemsize
    if expected > MAX_ARRAY_BYTES:
        raise DecodeError(f"{where}: {expected} bytes declared, limit {MAX_ARRAY_BYTES}")
    if len(data) != expected:
        raise DecodeError(f"{where}: {len(data)} bytes where shape {tuple(dims)} {name} needs {expected}")
    return np.frombuffer(data, dtype=name).reshape(dims)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic): they carry the size.
_JPEG_SOF = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})


def _encoded_size(data: bytes, fmt: str, where: str) -> tuple[int, int]:
    """Width and height from a PNG or JPEG header, read before decoding.

    A few hundred bytes of PNG can declare a 40000 x 40000 image: decoding first would allocate
    gigabytes, so the declared size is checked against the array limit before OpenCV sees it.
    """
    if fmt == "png":
        if len(data) < 24 or not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
            raise DecodeError(f"{where}: data is not png (no PNG signature and IHDR header)")
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if not data.startswith(b"\xff\xd8"):
        raise DecodeError(f"{where}: data is not jpeg (no start-of-image marker)")
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            break
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            i += 2
            continue
        length = int.from_bytes(data[i + 2 : i + 4], "big")
        if marker in _JPEG_SOF and i + 9 <= len(data):
            return int.from_bytes(data[i + 7 : i + 9], "big"), int.from_bytes(data[i + 5 : i + 7], "big")
        i += 2 + length
    raise DecodeError(f"{where}: jpeg data has no start-of-frame header with the image size")


def _unpack_image(value: Any, where: str) -> NDArray:
    if isinstance(value, dict) and _IMG in value:
        data = value.get("data")
        if value[_IMG] not in ("png", "jpeg") or not isinstance(data, (bytes, bytearray)):
            raise DecodeError(f"{where}: bad encoded image")
        if len(data) > MAX_ARRAY_BYTES:
            raise DecodeError(f"{where}: encoded image of {len(data)} bytes over the limit")
        width, height = _encoded_size(bytes(data), value[_IMG], where)
        if width * height * 3 > MAX_ARRAY_BYTES:
            raise DecodeError(
                f"{where}: {value[_IMG]} declares {width}x{height} pixels, over the limit of {MAX_ARRAY_BYTES} bytes"
            )
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if img is None or img.ndim != 3 or img.shape[2] != 3:
            raise DecodeError(f"{where}: {value[_IMG]} data does not decode to a colour image")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return _unpack_array(value, where, "uint8", (None, None, 3))


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
                kwargs[f.name] = _unpack_image(raw, sub)
            else:
                kwargs[f.name] = _unpack_array(raw, sub, f.metadata["dtype"], f.metadata["shape"])
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
    except DecodeError:
        raise
    except Exception as exc:  # a value the dataclass or numpy refuses
        raise DecodeError(f"{schema}: {type(exc).__name__}: {exc}") from None
    return typing.cast(M, msg)
