"""Every message on the bus and in recordings, its topic and key, and its timing trail.

A message is a keyword-only dataclass with a schema name and version (``stereovox.PointCloud/1``);
:mod:`common.codec` turns one into msgpack bytes and back.

The contract (ARCHITECTURE.md): ``frame_id`` is the capture sequence number and is monotonic,
``stamp_ns`` the capture time, and ``timing`` a trail of ``(stage, start_ns, end_ns)`` in wall
clock time that every stage extends; a stage joining two inputs carries the union of their trails.
"""

from __future__ import annotations

import time
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import numpy as np
import numpy.typing as npt

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
    # height above the road of its lowest voxel's centroid (m); 0 in recordings made before it
    floor_m: float = 0.0


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


#: truth classes whose box holds free space (a gantry's beam over the road, a sign's arm over a
#: lane, a U-shaped fence): what stands under or in one is not inside it.
OPEN_CLASSES: frozenset[str] = frozenset({"barrier", "sign", "fence"})


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
    origin: NDArray = array_field("float64", (3,), _zeros(3))  # where they were seen from: the left camera
    # corners followed from frame to frame (stereo_depth/keypoints.py): ids that persist while a
    # corner is followed, and where it is; empty when the stage does not follow any
    keypoint_ids: NDArray = array_field("int64", (None,), _zeros(0, dtype="int64"))
    keypoints: NDArray = array_field("float32", (None, 3), _zeros(0, 3, dtype="float32"))
    keypoint_std: NDArray = array_field("float32", (None,), _zeros(0, dtype="float32"))  # along the ray (m)


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
    # where the cloud was seen from (vehicle x, y) and the slopes dy / dx of its leftmost and rightmost
    # bearings: the image's side edges, which cut what stands beside the road. Unknown (older
    # recordings, an empty cloud) when the left slope is not above the right one.
    view: NDArray = array_field("float64", (4,), _zeros(4))
    # the cloud's followed corners (PointCloud.keypoint_ids) that have lain in a cluster's voxel since
    # they were first followed (voxel_mapper/core.py), placed in the world with the clusters
    keypoint_ids: NDArray = array_field("int64", (None,), _zeros(0, dtype="int64"))
    keypoints: NDArray = array_field("float64", (None, 3), _zeros(0, 3))
    keypoint_std: NDArray = array_field("float32", (None,), _zeros(0, dtype="float32"))
    # clusters centred beyond the volume's far end, in its lookahead (VolumeConfig.lookahead_m): the
    # tracker follows them so that what comes into range arrives with a track; nothing else uses them
    beyond: list[Cluster] = field(default_factory=list)


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
