"""Stereovox messages as Foxglove's own schemas, for the live server and the exporter alike.

Foxglove decodes protobuf but not msgpack, so a stereovox message is never shown as it is: it is
turned into the well-known ``foxglove.*`` messages the app draws natively (images, point
clouds, scene cubes and arrows, transforms). The functions here are pure (a message in, Foxglove
messages out); :class:`Converter` only adds the one thing that needs memory, the ego trajectory.

Frames of reference are Foxglove frame ids: ``world`` (the stereovox world), ``vehicle`` (moved
by the world->vehicle transform of each ego pose) and ``camera`` (the left camera, fixed on the
vehicle by the calibration), so the 3D panel places everything from the transforms alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from foxglove.messages import (
    ArrowPrimitive,
    CameraCalibration,
    Color,
    CompressedImage,
    CubePrimitive,
    FrameTransform,
    LinePrimitive,
    LinePrimitiveLineType,
    PackedElementField,
    PackedElementFieldNumericType,
    Point3,
    PointCloud,
    Pose,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    TextPrimitive,
    Timestamp,
    Vector3,
)
from scipy.spatial.transform import Rotation

from common import messages as sv

NDArray = npt.NDArray[Any]
#: one converted message: the Foxglove topic it goes on and the message.
Converted = tuple[str, Any]

WORLD, VEHICLE, CAMERA = "world", "vehicle", "camera"

#: Foxglove topic -> Foxglove message type; every channel the live server and exporter open.
TOPICS: dict[str, type] = {
    "/camera/left": CompressedImage,
    "/camera/calibration": CameraCalibration,
    "/disparity": CompressedImage,
    "/tf": FrameTransform,
    "/points": PointCloud,
    "/voxels": SceneUpdate,
    "/clusters": SceneUpdate,
    "/obstacles": SceneUpdate,
    "/trajectory": SceneUpdate,
    "/groundtruth/objects": SceneUpdate,
}

#: track colours (RGBA 0..1): the paper's figures draw moving obstacles red, static ones green.
MOVING = (0.95, 0.15, 0.1, 0.6)
STATIONARY = (0.1, 0.85, 0.2, 0.6)
ACCEPTANCE = (1.0, 0.85, 0.1, 0.4)
GHOST = (0.6, 0.6, 0.6, 0.3)
TRUTH = (1.0, 1.0, 1.0, 0.25)
#: JPEG quality of the left image sent to Foxglove.
JPEG_QUALITY = 85
#: the velocity arrow is the distance covered in this many seconds.
ARROW_SECONDS = 1.0


def obstacle_rgba(obstacle: sv.Obstacle) -> tuple[float, float, float, float]:
    """Colour of a track: red moving, green stationary; new and lost tracks paler."""
    if obstacle.state == "acceptance":
        return ACCEPTANCE
    if obstacle.state == "ghost":
        return GHOST
    return MOVING if obstacle.moving else STATIONARY


def timestamp(stamp_ns: int) -> Timestamp:
    return Timestamp(int(stamp_ns) // 1_000_000_000, int(stamp_ns) % 1_000_000_000)


def _color(rgba: Sequence[float]) -> Color:
    r, g, b, a = (float(v) for v in rgba)
    return Color(r=r, g=g, b=b, a=a)


def _vec(v: Sequence[float] | NDArray) -> Vector3:
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _quat(rotation: NDArray) -> Quaternion:
    x, y, z, w = Rotation.from_matrix(np.asarray(rotation, dtype=np.float64)).as_quat()
    return Quaternion(x=float(x), y=float(y), z=float(z), w=float(w))


def pose(matrix: NDArray) -> Pose:
    """A 4x4 pose (local -> parent) as a Foxglove Pose."""
    return Pose(position=_vec(matrix[:3, 3]), orientation=_quat(matrix[:3, :3]))


#: the orientation of every axis-aligned box (a voxel map holds thousands: no conversion each).
_UNTURNED = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def _at(position: NDArray, rotation: NDArray | None = None) -> Pose:
    return Pose(position=_vec(position), orientation=_UNTURNED if rotation is None else _quat(rotation))


def transform(parent: str, child: str, matrix: NDArray, stamp_ns: int) -> FrameTransform:
    """``child`` placed in ``parent`` by a local -> parent pose."""
    return FrameTransform(
        timestamp=timestamp(stamp_ns),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=_vec(matrix[:3, 3]),
        rotation=_quat(matrix[:3, :3]),
    )


def image(frame: sv.StereoFrame) -> list[Converted]:
    """Left image as JPEG, its pinhole model and where the camera sits on the vehicle."""
    bgr = cv2.cvtColor(np.ascontiguousarray(frame.left), cv2.COLOR_RGB2BGR)
    ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    stamp = timestamp(frame.stamp_ns)
    c = frame.calib
    k = [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0]
    p = [c.fx, 0.0, c.cx, 0.0, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    calibration = CameraCalibration(
        timestamp=stamp, frame_id=CAMERA, width=c.width, height=c.height, distortion_model="plumb_bob",
        D=[0.0] * 5, K=k, R=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], P=p,
    )
    out: list[Converted] = [
        ("/tf", transform(VEHICLE, CAMERA, c.cam_to_vehicle, frame.stamp_ns)),
        ("/camera/calibration", calibration),
    ]
    if ok:
        left = CompressedImage(timestamp=stamp, frame_id=CAMERA, data=jpeg.tobytes(), format="jpeg")
        out.append(("/camera/left", left))
    return out


def disparity(msg: sv.Disparity) -> list[Converted]:
    """Disparity as a colour-mapped JPEG (near warm, far cool, invalid black) on the camera frame."""
    d = np.asarray(msg.disparity, dtype=np.float32)
    valid = np.isfinite(d) & (d > 0)
    top = float(np.percentile(d[valid], 99)) if valid.any() else 1.0
    scaled = np.zeros(d.shape, dtype=np.uint8)
    scaled[valid] = np.clip(d[valid] / max(top, 1e-6) * 255.0, 0, 255).astype(np.uint8)
    coloured = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    coloured[~valid] = 0
    ok, jpeg = cv2.imencode(".jpg", coloured, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        return []
    image = CompressedImage(timestamp=timestamp(msg.stamp_ns), frame_id=CAMERA, data=jpeg.tobytes(), format="jpeg")
    return [("/disparity", image)]


_POINT_FIELDS = [
    PackedElementField(name="x", offset=0, type=PackedElementFieldNumericType.Float32),
    PackedElementField(name="y", offset=4, type=PackedElementFieldNumericType.Float32),
    PackedElementField(name="z", offset=8, type=PackedElementFieldNumericType.Float32),
    PackedElementField(name="red", offset=12, type=PackedElementFieldNumericType.Uint8),
    PackedElementField(name="green", offset=13, type=PackedElementFieldNumericType.Uint8),
    PackedElementField(name="blue", offset=14, type=PackedElementFieldNumericType.Uint8),
    PackedElementField(name="alpha", offset=15, type=PackedElementFieldNumericType.Uint8),
]
_POINT_DTYPE = np.dtype([("xyz", "<f4", 3), ("rgba", "u1", 4)])


def point_cloud(cloud: sv.PointCloud) -> list[Converted]:
    """Coloured points, 16 bytes each, in the vehicle frame they were seen in."""
    packed = np.empty(len(cloud.points), dtype=_POINT_DTYPE)
    packed["xyz"] = cloud.points
    packed["rgba"][:, :3] = cloud.colors
    packed["rgba"][:, 3] = 255
    msg = PointCloud(
        timestamp=timestamp(cloud.stamp_ns), frame_id=VEHICLE, pose=pose(np.eye(4)),
        point_stride=_POINT_DTYPE.itemsize, fields=_POINT_FIELDS, data=packed.tobytes(),
    )
    return [("/points", msg)]


def _replace_all(entities: list[SceneEntity], stamp_ns: int) -> SceneUpdate:
    """An update that clears the previous frame's entities before drawing this frame's."""
    wipe = SceneEntityDeletion(timestamp=timestamp(stamp_ns), type=SceneEntityDeletionType.All)
    return SceneUpdate(deletions=[wipe], entities=entities)


def _entity(name: str, stamp_ns: int, frame: str = WORLD, **primitives: Any) -> SceneEntity:
    return SceneEntity(timestamp=timestamp(stamp_ns), frame_id=frame, id=name, **primitives)


def _box(lo: NDArray, hi: NDArray, rgba: Sequence[float]) -> CubePrimitive:
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return CubePrimitive(pose=_at((lo + hi) / 2), size=_vec(np.maximum(hi - lo, 1e-3)), color=_color(rgba))


def clusters(msg: sv.Clusters) -> list[Converted]:
    """Every occupied voxel of each cluster as a cube in the cluster's colour, and cluster boxes."""
    edge = float(msg.voxel_edge)
    voxel_entities, box_entities = [], []
    for cl in msg.clusters:
        rgb = np.clip(np.asarray(cl.color_mean_rgb, dtype=np.float64), 0.0, 1.0)
        size = _vec((edge, edge, edge))
        colour = _color((*rgb, 0.9))
        cubes = [CubePrimitive(pose=_at((v + 0.5) * edge), size=size, color=colour) for v in np.asarray(cl.voxels)]
        voxel_entities.append(_entity(f"cluster/{cl.id}/voxels", msg.stamp_ns, cubes=cubes))
        box = _box(cl.bbox_min, cl.bbox_max, (*rgb, 0.25))
        box_entities.append(_entity(f"cluster/{cl.id}", msg.stamp_ns, cubes=[box]))
    return [
        ("/voxels", _replace_all(voxel_entities, msg.stamp_ns)),
        ("/clusters", _replace_all(box_entities, msg.stamp_ns)),
    ]


def _arrow(start: NDArray, velocity: NDArray, rgba: Sequence[float]) -> ArrowPrimitive | None:
    """An arrow from ``start`` along ``velocity``, as long as the distance covered in ARROW_SECONDS."""
    length = float(np.linalg.norm(velocity)) * ARROW_SECONDS
    if length < 1e-3:
        return None
    direction = np.asarray(velocity, dtype=np.float64) / np.linalg.norm(velocity)
    # Foxglove arrows point along their local +x: rotate +x onto the velocity's direction.
    rotation, _ = Rotation.align_vectors([direction], [[1.0, 0.0, 0.0]])
    head = min(0.5, 0.3 * length)
    return ArrowPrimitive(
        pose=Pose(position=_vec(start), orientation=_quat(rotation.as_matrix())),
        shaft_length=max(length - head, 1e-3), shaft_diameter=0.08, head_length=head, head_diameter=0.25,
        color=_color((*rgba[:3], 1.0)),
    )


def obstacles(msg: sv.Obstacles) -> list[Converted]:
    """Each track as a box coloured by state, its velocity arrow and a label; plus the ego pose."""
    entities = []
    for ob in msg.obstacles:
        rgba = obstacle_rgba(ob)
        arrow = _arrow(np.asarray(ob.centroid), np.asarray(ob.velocity), rgba)
        label = TextPrimitive(
            pose=_at(np.array([ob.centroid[0], ob.centroid[1], ob.bbox_max[2] + 0.3])), billboard=True,
            font_size=14.0, scale_invariant=True, color=_color((1, 1, 1, 1)),
            text=f"#{ob.id} {ob.speed:.1f} m/s" + (" moving" if ob.moving else ""),
        )
        entities.append(_entity(
            f"obstacle/{ob.id}", msg.stamp_ns, cubes=[_box(ob.bbox_min, ob.bbox_max, rgba)],
            arrows=[arrow] if arrow is not None else [], texts=[label],
        ))
    return [
        ("/tf", transform(WORLD, VEHICLE, msg.ego_pose, msg.stamp_ns)),
        ("/obstacles", _replace_all(entities, msg.stamp_ns)),
    ]


def trajectory(positions: NDArray, stamp_ns: int) -> list[Converted]:
    """The ego path so far as one line in the world frame."""
    points = [Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in positions]
    line = LinePrimitive(
        type=LinePrimitiveLineType.LineStrip, pose=pose(np.eye(4)), thickness=0.15, points=points,
        color=_color((0.2, 0.6, 1.0, 1.0)),
    )
    return [("/trajectory", _replace_all([_entity("ego/trajectory", stamp_ns, lines=[line])], stamp_ns))]


def ground_truth(msg: sv.GroundTruthObjects) -> list[Converted]:
    """True objects as pale boxes turned by their yaw, to compare with the tracks."""
    entities = []
    for obj in msg.objects:
        rot = Rotation.from_euler("z", float(obj.yaw)).as_matrix()
        cube = CubePrimitive(pose=_at(np.asarray(obj.center), rot), size=_vec(obj.size), color=_color(TRUTH))
        entities.append(_entity(f"truth/{obj.id}", msg.stamp_ns, cubes=[cube]))
    return [("/groundtruth/objects", _replace_all(entities, msg.stamp_ns))]


class Converter:
    """Turns each stereovox message into its Foxglove messages; remembers the ego trajectory.

    The trajectory is drawn from the odometry when it is present and from the tracker's ego pose
    otherwise (a recording of the tracker alone still shows where the vehicle went).
    """

    def __init__(self, max_trajectory: int = 5000) -> None:
        # The line is sent whole with every frame (a viewer may join or seek at any time), so
        # its length is capped: 5000 poses is over eight minutes at 10 Hz.
        self.max_trajectory = max_trajectory
        self._positions: list[NDArray] = []
        self._last_frame = -1
        self._epoch = 0
        self._odometry_seen = False

    def convert(self, topic: str, msg: sv.Message) -> list[Converted]:
        """Foxglove messages for one stereovox message on ``topic``; unknown topics give none."""
        if isinstance(msg, sv.StereoFrame):
            return image(msg)
        if isinstance(msg, sv.PointCloud):
            return point_cloud(msg)
        if isinstance(msg, sv.Disparity):
            return disparity(msg)
        if isinstance(msg, sv.Clusters):
            return clusters(msg)
        if isinstance(msg, sv.Obstacles):
            out = obstacles(msg)
            if self._odometry_seen:
                return out
            return out + self._extend(msg.ego_pose, msg.frame_id, msg.stamp_ns, msg.world_epoch)
        if isinstance(msg, sv.EgoMotion):
            self._odometry_seen = True
            moved = transform(WORLD, VEHICLE, msg.pose, msg.stamp_ns)
            return [("/tf", moved), *self._extend(msg.pose, msg.frame_id, msg.stamp_ns, msg.world_epoch)]
        if isinstance(msg, sv.GroundTruthObjects):
            return ground_truth(msg)
        return []

    def _extend(self, ego_pose: NDArray, frame_id: int, stamp_ns: int, epoch: int) -> list[Converted]:
        if epoch != self._epoch:  # the world was re-anchored: old positions are in another frame
            self._epoch = epoch
            self._positions.clear()
        if frame_id != self._last_frame:
            self._last_frame = frame_id
            self._positions.append(np.asarray(ego_pose)[:3, 3].copy())
            del self._positions[: -self.max_trajectory]
        return trajectory(np.array(self._positions), stamp_ns)


class Channels:
    """One typed Foxglove channel per topic of :data:`TOPICS`, opened at once in ``context``.

    Opening them all up front lets a live viewer list every channel before the first frame.
    """

    def __init__(self, context: Any) -> None:
        import foxglove.channels

        self._channels = {
            topic: getattr(foxglove.channels, f"{cls.__name__}Channel")(topic, context=context)
            for topic, cls in TOPICS.items()
        }
        self.logged = 0

    def log(self, converted: Sequence[Converted], log_time_ns: int | None = None) -> None:
        for topic, message in converted:
            self._channels[topic].log(message, log_time=log_time_ns)
            self.logged += 1

    def watched(self, topics: Sequence[str]) -> bool:
        """Whether any sink (a subscribed viewer, an open file) takes one of ``topics`` now."""
        return any(self._channels[topic].has_sinks() for topic in topics)

    def close(self) -> None:
        for channel in self._channels.values():
            channel.close()
