"""Drawing a frame's tracks the way the paper's Figs. 1 and 6 do: boxes on the image, a map beside it.

The image overlay projects each track's world box through the same chain the pipeline uses:
world -> vehicle by the inverse of the ego pose the tracker reported, vehicle -> camera by the
inverse of the calibration's ``cam_to_vehicle``, then the pinhole model. The bird's-eye panel is
drawn in the current vehicle frame (x forward up the page, y left to the left), so the ego
vehicle stays put and the world moves past it. Images are RGB uint8 throughout.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from common.geometry import invert, transform
from common.messages import Calibration, Cluster, GroundTruthObject, Obstacle

NDArray = npt.NDArray[Any]
RGB = tuple[int, int, int]

MOVING: RGB = (230, 30, 20)
STATIONARY: RGB = (30, 210, 50)
ACCEPTANCE: RGB = (250, 210, 30)
GHOST: RGB = (150, 150, 150)
TRAJECTORY: RGB = (60, 150, 255)
TRUTH: RGB = (150, 150, 150)
#: points nearer the camera than this (m) are not projected.
NEAR_M = 0.2
#: the velocity arrow shows the distance covered in this many seconds.
ARROW_SECONDS = 1.0
#: the 12 edges of a box whose corners are numbered by (x, y, z) bits.
EDGES: tuple[tuple[int, int], ...] = (
    (0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7),
)


def track_colour(obstacle: Obstacle) -> RGB:
    """Red moving, green stationary; yellow while being accepted, grey while lost."""
    if obstacle.state == "acceptance":
        return ACCEPTANCE
    if obstacle.state == "ghost":
        return GHOST
    return MOVING if obstacle.moving else STATIONARY


def cluster_colour(cluster_id: int) -> RGB:
    """A colour of its own for each cluster id: hues a golden angle apart stay distinct."""
    hue = int((cluster_id * 0.618034 % 1.0) * 180)
    r, g, b = cv2.cvtColor(np.array([[[hue, 150, 220]]], dtype=np.uint8), cv2.COLOR_HSV2RGB)[0, 0]
    return int(r), int(g), int(b)


def box_corners(lo: NDArray, hi: NDArray) -> NDArray:
    """The 8 corners of an axis-aligned box; corner i takes hi on axis a where bit a of i is set."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    bits = (np.arange(8)[:, None] >> np.arange(3)) & 1
    return np.where(bits == 1, hi, lo)


def world_to_camera(ego_pose: NDArray, calib: Calibration) -> NDArray:
    """The 4x4 taking world points into the left camera's frame at this ego pose."""
    return invert(np.asarray(calib.cam_to_vehicle, dtype=np.float64)) @ invert(np.asarray(ego_pose, dtype=np.float64))


def project(points_world: NDArray, world_cam: NDArray, calib: Calibration) -> tuple[NDArray, NDArray]:
    """Pixel coordinates (Nx2) of world points and whether each lies in front of the camera."""
    cam = transform(world_cam, np.asarray(points_world, dtype=np.float64))
    front = cam[:, 2] > NEAR_M
    z = np.where(front, cam[:, 2], 1.0)
    uv = np.stack([calib.fx * cam[:, 0] / z + calib.cx, calib.fy * cam[:, 1] / z + calib.cy], axis=1)
    return uv, front


def _pt(uv: NDArray) -> tuple[int, int]:
    return round(float(uv[0])), round(float(uv[1]))


def draw_track_on_image(image: NDArray, obstacle: Obstacle, world_cam: NDArray, calib: Calibration) -> None:
    """The track's 3D box, its velocity arrow from the centroid and its id, drawn in place."""
    colour = track_colour(obstacle)
    uv, front = project(box_corners(obstacle.bbox_min, obstacle.bbox_max), world_cam, calib)
    for a, b in EDGES:
        if front[a] and front[b]:
            cv2.line(image, _pt(uv[a]), _pt(uv[b]), colour, 2, cv2.LINE_AA)
    centre = np.asarray(obstacle.centroid, dtype=np.float64)
    tip = centre + np.asarray(obstacle.velocity, dtype=np.float64) * ARROW_SECONDS
    ends, ok = project(np.stack([centre, tip]), world_cam, calib)
    if ok.all() and np.linalg.norm(ends[1] - ends[0]) >= 2.0:
        cv2.arrowedLine(image, _pt(ends[0]), _pt(ends[1]), (255, 255, 0), 2, cv2.LINE_AA, tipLength=0.25)
    if front.any():
        top = uv[front][np.argmin(uv[front][:, 1])]
        label = f"{obstacle.id} {obstacle.speed:.1f}m/s"
        at = _pt(top - np.array([0.0, 4.0]))
        cv2.putText(image, label, at, cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)


@dataclass(frozen=True)
class BirdsEye:
    """A top view of the vehicle frame: ``ahead_m`` forward, ``behind_m`` back, ``side_m`` each side."""

    size_px: int
    ahead_m: float = 40.0
    behind_m: float = 5.0
    side_m: float = 22.5

    @property
    def scale(self) -> float:
        """Pixels per metre (the panel is square: forward range fits its height)."""
        return self.size_px / (self.ahead_m + self.behind_m)

    def pixels(self, points_vehicle: NDArray) -> NDArray:
        """Panel pixels (Nx2 int32) of vehicle-frame points: x up the page, y to the left."""
        p = np.asarray(points_vehicle, dtype=np.float64).reshape(-1, 3)
        u = self.size_px / 2 - p[:, 1] * self.scale
        v = self.size_px - (p[:, 0] + self.behind_m) * self.scale
        return np.round(np.stack([u, v], axis=1)).astype(np.int32)

    def canvas(self) -> NDArray:
        """A dark panel with a line every 10 m and the ego vehicle at the origin."""
        panel = np.full((self.size_px, self.size_px, 3), 24, dtype=np.uint8)
        for x in np.arange(0.0, self.ahead_m + 1e-6, 10.0):
            (u0, v), (u1, _) = self.pixels(np.array([[x, self.side_m, 0.0], [x, -self.side_m, 0.0]]))
            cv2.line(panel, (int(u0), int(v)), (int(u1), int(v)), (60, 60, 60), 1)
            cv2.putText(panel, f"{x:.0f} m", (4, int(v) - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (120, 120, 120), 1)
        ego = self.pixels(np.array([[1.5, 0.0, 0.0], [-1.0, 0.8, 0.0], [-1.0, -0.8, 0.0]]))
        cv2.fillPoly(panel, [ego], TRAJECTORY)
        legend = (("moving", MOVING), ("stationary", STATIONARY), ("new", ACCEPTANCE), ("lost", GHOST),
                  ("truth", TRUTH), ("ego path", TRAJECTORY))
        x = 4
        for name, colour in legend:
            cv2.putText(panel, name, (x, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, colour, 1, cv2.LINE_AA)
            x += cv2.getTextSize(name, cv2.FONT_HERSHEY_SIMPLEX, 0.35, 1)[0][0] + 8
        return panel

    def draw_voxels(self, panel: NDArray, clusters: Sequence[Cluster], edge: float, world_vehicle: NDArray) -> None:
        """Every cluster's voxels as small squares, one colour per cluster (as the paper's Fig. 6)."""
        side = max(1, round(edge * self.scale))
        h, w = panel.shape[:2]
        for cl in clusters:
            centres = (np.asarray(cl.voxels, dtype=np.float64) + 0.5) * edge
            px = self.pixels(transform(world_vehicle, centres)) - side // 2
            colour = np.array(cluster_colour(cl.id), dtype=np.uint8)
            for du in range(side):
                for dv in range(side):
                    u, v = px[:, 0] + du, px[:, 1] + dv
                    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
                    panel[v[inside], u[inside]] = colour

    def _footprint(self, panel: NDArray, lo: NDArray, hi: NDArray, world_vehicle: NDArray, colour: RGB,
                   thickness: int) -> None:
        corners = box_corners(lo, hi)[[0, 1, 3, 2]]  # the bottom face, in order around it
        cv2.polylines(panel, [self.pixels(transform(world_vehicle, corners))], True, colour, thickness, cv2.LINE_AA)

    def draw_tracks(self, panel: NDArray, obstacles: Sequence[Obstacle], world_vehicle: NDArray) -> None:
        """Each track's footprint in its state colour; confirmed tracks also get their velocity arrow."""
        for ob in obstacles:
            colour = track_colour(ob)
            self._footprint(panel, ob.bbox_min, ob.bbox_max, world_vehicle, colour, 2)
            if ob.state != "tracked":
                continue  # new and lost tracks' velocities are guesses: arrows would only clutter
            centre = np.asarray(ob.centroid, dtype=np.float64)
            tip = centre + np.asarray(ob.velocity) * ARROW_SECONDS
            ends = self.pixels(transform(world_vehicle, np.stack([centre, tip])))
            if np.abs(ends[1] - ends[0]).max() >= 2:
                cv2.arrowedLine(panel, tuple(map(int, ends[0])), tuple(map(int, ends[1])), (255, 255, 0), 1,
                                cv2.LINE_AA, tipLength=0.3)

    def draw_truth(self, panel: NDArray, objects: Sequence[GroundTruthObject], world_vehicle: NDArray) -> None:
        """True objects as thin outlines turned by their yaw."""
        for obj in objects:
            length, width = float(obj.size[0]), float(obj.size[1])
            c, s = np.cos(obj.yaw), np.sin(obj.yaw)
            local = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
            xy = np.asarray(obj.center)[:2] + local @ np.array([[c, s], [-s, c]])
            corners = np.column_stack([xy, np.full(4, float(obj.center[2]))])
            cv2.polylines(panel, [self.pixels(transform(world_vehicle, corners))], True, TRUTH, 1, cv2.LINE_AA)

    def draw_trajectory(self, panel: NDArray, positions_world: NDArray, world_vehicle: NDArray) -> None:
        """The ego path so far, seen from where the vehicle is now."""
        if len(positions_world) >= 2:
            px = self.pixels(transform(world_vehicle, np.asarray(positions_world, dtype=np.float64)))
            cv2.polylines(panel, [px], False, TRAJECTORY, 2, cv2.LINE_AA)
