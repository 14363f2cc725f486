"""A rectified stereo pair of a world at one instant, with its exact ground truth.

Both views are ray cast from their own camera centres (the right one ``baseline`` metres along
the left camera's x axis), then shaded from the same world-anchored textures. The left view's
depth gives the true disparity ``fx * baseline / Z``; a pixel whose point is hidden in the right
view (the right view sees something nearer at the matching pixel) or falls outside it is NaN.

A real sensor's pixel integrates the light over its area, so a pole's edge half a pixel in is a
half-bright pixel. One ray per pixel instead snaps every silhouette to whole pixels in each view
independently, and a thin object's disparity is then only known to half a pixel whatever the
matcher (measured: a 4-pixel pole at 27 m matched 0.25 px near, a metre). Pixels that an edge
crosses (their neighbourhood holds another surface or another face's light) are therefore the
mean of ``samples`` x ``samples`` rays spread over their area; elsewhere the texture is already
filtered to the pixel's footprint and the centre ray stands for the whole pixel. The truth (depth,
disparity, object ids) stays the centre ray's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import ConfigError
from common.geometry import camera_to_vehicle, make_pose
from common.messages import Calibration
from common.scenarios import raycast
from common.scenarios.ground import cast_ground
from common.scenarios.raycast import Box, Buffers, Packed
from common.scenarios.sensor import expose
from common.scenarios.texture import Texture
from common.scenarios.world import Material, ThingState, World

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

GROUND_MATERIALS = (
    Material((0.30, 0.30, 0.31), amp=0.35, texel=0.02),  # asphalt
    Material((0.62, 0.60, 0.56), amp=0.25, texel=0.03, phase=101.0),  # sidewalk
    Material((0.72, 0.72, 0.70), amp=0.20, texel=0.02, phase=57.0),  # kerb
    Material((0.34, 0.42, 0.22), amp=0.40, texel=0.03, phase=211.0),  # verge
)
PAINT = np.array([0.88, 0.88, 0.86], np.float32)
#: ignore objects farther than this (m): they cover a pixel or two at most.
DRAW_DISTANCE = 150.0


@dataclass(frozen=True)
class Rig:
    """The stereo rig: pinhole intrinsics, baseline and where the left camera sits on the vehicle."""

    width: int = 640
    height: int = 480
    focal: float = 600.0
    baseline: float = 0.4
    camera_height: float = 1.5
    samples: int = 3  # rays per pixel side where an edge crosses the pixel (odd; 1 = one ray per pixel)

    def calibration(self) -> Calibration:
        return Calibration(
            fx=self.focal, fy=self.focal, cx=self.width / 2, cy=self.height / 2, baseline=self.baseline,
            width=self.width, height=self.height, cam_to_vehicle=camera_to_vehicle(self.camera_height),
        )


@dataclass
class Rendered:
    """One stereo pair and what is true about it."""

    left: npt.NDArray[np.uint8]
    right: npt.NDArray[np.uint8]
    disparity: F32  # left image, NaN where invalid
    depth: F32  # left camera Z, inf for sky
    object_ids: npt.NDArray[np.int32]  # left image, -1 for ground and sky
    visible_pixels: dict[int, int]
    visible_fraction: dict[int, float]
    states: list[ThingState]
    ego_pose: F64


class Renderer:
    """Renders one world with one rig; per-frame work is :meth:`render`."""

    def __init__(self, world: World, rig: Rig) -> None:
        self.world = world
        self.rig = rig
        self.calib = rig.calibration()
        self.texture = Texture()
        us, vs = np.meshgrid(np.arange(rig.width, dtype=np.float32), np.arange(rig.height, dtype=np.float32))
        # camera-frame ray directions (a, b, 1) per pixel, row-major
        self._a = ((us - self.calib.cx) / rig.focal).ravel()[:, None]
        self._b = ((vs - self.calib.cy) / rig.focal).ravel()[:, None]
        self._intr = (rig.focal, rig.focal, self.calib.cx, self.calib.cy)
        if rig.samples < 1 or rig.samples % 2 == 0:
            raise ConfigError(f"samples per pixel side must be odd and positive, got {rig.samples}")
        spread = (np.arange(rig.samples, dtype=np.float32) + 0.5) / rig.samples - 0.5
        sx, sy = (grid.ravel() for grid in np.meshgrid(spread, spread))
        off_centre = (sx != 0) | (sy != 0)  # the centre ray is cast for every pixel anyway
        self._sub_offsets = np.stack([sx[off_centre], sy[off_centre]], axis=1)

    def camera_poses(self, ego_pose: F64) -> tuple[F64, F64]:
        left = ego_pose @ self.calib.cam_to_vehicle
        return left, left @ make_pose(np.eye(3), [self.rig.baseline, 0.0, 0.0])

    def boxes(self, states: list[ThingState], ego_pose: F64) -> tuple[list[Box], list[tuple[float, ...]]]:
        """World boxes of every part near enough to matter, and the surface table (rgb, amp, texel, phase)."""
        table = [(*m.rgb, m.amp, m.texel, m.phase) for m in GROUND_MATERIALS]
        boxes: list[Box] = []
        for st in states:
            if np.linalg.norm(st.pose[:2, 3] - ego_pose[:2, 3]) > DRAW_DISTANCE:
                continue
            rot = st.pose[:3, :3]
            for k, part in enumerate(st.thing.parts):
                center = st.pose[:3, 3] + rot @ np.asarray(part.center)
                m = part.material
                table.append((*m.rgb, m.amp, m.texel, m.phase + 53.0 * st.thing.id + 17.0 * k))
                boxes.append(Box(center, rot, np.asarray(part.size) / 2, len(table) - 1, st.thing.id))
        return boxes, table

    def world_dirs(self, cam_pose: F64) -> F32:
        """Per-pixel ray directions in the world (camera z component 1, so t is depth)."""
        rot = cam_pose[:3, :3].astype(np.float32)
        return self._a * rot[:, 0] + self._b * rot[:, 1] + rot[:, 2]

    def cast(self, cam_pose: F64, boxes: Packed) -> Buffers:
        """Ground then every box whose screen rectangle is in view, nearest surface winning."""
        origin = cam_pose[:3, 3]
        dirs = self.world_dirs(cam_pose)
        buf = cast_ground(self.world.road, origin, dirs, self.rig.focal)
        w, h = self.rig.width, self.rig.height
        rects = boxes.screen_rects(origin, cam_pose[:3, :3], self._intr, (0, w, 0, h))
        raycast.cast_boxes(buf, boxes, rects, origin, dirs, w, self.rig.focal)
        return buf

    def view(self, cam_pose: F64, boxes: Packed, table: list[tuple[float, ...]]) -> tuple[F32, Buffers]:
        """One camera's linear RGB image (HxWx3, edges area-sampled) and its centre rays' buffers."""
        buf = self.cast(cam_pose, boxes)
        img = self.shade(buf, table, cam_pose, self._a[:, 0], self._b[:, 0])
        edges = self._edge_pixels(buf)
        if len(edges) and len(self._sub_offsets):
            per_pixel = len(self._sub_offsets)
            xs, ys = np.repeat(edges % self.rig.width, per_pixel), np.repeat(edges // self.rig.width, per_pixel)
            offsets = np.tile(self._sub_offsets, (len(edges), 1))
            a = (xs + offsets[:, 0] - np.float32(self.calib.cx)) / np.float32(self.rig.focal)
            b = (ys + offsets[:, 1] - np.float32(self.calib.cy)) / np.float32(self.rig.focal)
            rot = cam_pose[:3, :3].astype(np.float32)
            dirs = a[:, None] * rot[:, 0] + b[:, None] * rot[:, 1] + rot[:, 2]
            origin = cam_pose[:3, 3]
            sub = cast_ground(self.world.road, origin, dirs, self.rig.focal)
            rects = boxes.screen_rects(origin, cam_pose[:3, :3], self._intr, (0, self.rig.width, 0, self.rig.height))
            raycast.cast_boxes_at(sub, boxes, rects, origin, dirs, xs, ys, self.rig.focal)
            colours = self.shade(sub, table, cam_pose, a, b).reshape(len(edges), per_pixel, 3)
            img[edges] = (img[edges] + colours.sum(axis=1)) / np.float32(per_pixel + 1)
        return img.reshape(self.rig.height, self.rig.width, 3), buf

    def _edge_pixels(self, buf: Buffers) -> npt.NDArray[np.int64]:
        """Flat indices of pixels next to (8-neighbourhood) another surface or another face's light."""
        shape = (self.rig.height, self.rig.width)
        kernel = np.ones((3, 3), np.uint8)
        edge = np.zeros(shape, bool)
        for values in (buf.surface.astype(np.float32), buf.light):
            img = values.reshape(shape)
            edge |= cv2.dilate(img, kernel) != cv2.erode(img, kernel)
        return np.flatnonzero(edge)

    def shade(self, buf: Buffers, table: list[tuple[float, ...]], cam_pose: F64, a: F32, b: F32) -> F32:
        """Linear RGB 0..1 per ray (n x 3): texture around each surface's colour, road paint, face light, sky.

        ``a`` and ``b`` are the rays' camera-frame directions (x / z, y / z), which the sky's shade needs.
        """
        look = self.world.look
        tab = np.asarray(table, np.float32)
        img = np.empty((len(buf.depth), 3), np.float32)
        solid = buf.surface >= 0
        surf = buf.surface[solid]
        noise = self.texture.sample(buf.u[solid], buf.v[solid], tab[surf, 4], buf.footprint[solid], tab[surf, 5])
        colour = tab[surf, :3] * (1.0 + look.contrast * tab[surf, 3] * noise)[:, None]
        paint = buf.paint[solid][:, None]
        colour = colour * (1 - paint) + PAINT * paint
        img[solid] = colour * buf.light[solid][:, None]
        sky = ~solid
        a, b = a[sky], b[sky]
        rot = cam_pose[:3, :3]
        up = (a * rot[2, 0] + b * rot[2, 1] + rot[2, 2]) / np.sqrt(a * a + b * b + 1)
        mix = np.clip(up * 3.0, 0.0, 1.0)[:, None]
        img[sky] = np.array([0.85, 0.88, 0.92], np.float32) * (1 - mix) + np.array([0.45, 0.6, 0.85]) * mix
        return img * np.float32(look.brightness)

    def render(self, t: float, rng: np.random.Generator) -> Rendered:
        """The pair at time ``t``; ``rng`` drives sensor noise only."""
        ego = self.world.ego_pose(t)
        states = self.world.states(t)
        box_list, table = self.boxes(states, ego)
        boxes = Packed.of(box_list)
        cam_l, cam_r = self.camera_poses(ego)
        linear_l, buf_l = self.view(cam_l, boxes, table)
        linear_r, buf_r = self.view(cam_r, boxes, table)
        look = self.world.look
        left = expose(linear_l, 1.0, look, rng)
        right = expose(linear_r, look.exposure_ratio, look, rng)
        shape = (self.rig.height, self.rig.width)
        disparity = self.true_disparity(buf_l.depth.reshape(shape), buf_r.depth.reshape(shape))
        ids = buf_l.obj.reshape(shape)
        pixels, fractions = self.visibility(ids, boxes, cam_l)
        return Rendered(left, right, disparity, buf_l.depth.reshape(shape), ids, pixels, fractions, states, ego)

    def true_disparity(self, depth_l: F32, depth_r: F32) -> F32:
        """``fx * B / Z`` of the left view, NaN where the right view cannot see the same point."""
        w = depth_l.shape[1]
        with np.errstate(divide="ignore"):
            disp = (self.rig.focal * self.rig.baseline / depth_l).astype(np.float32)
        cols = np.arange(w, dtype=np.float32)[None, :] - disp
        inside = np.isfinite(depth_l) & (cols >= -0.5) & (cols <= w - 0.5)
        ci = np.clip(np.rint(np.nan_to_num(cols, nan=0.0)), 0, w - 1).astype(np.int64)
        seen = np.take_along_axis(depth_r, ci, axis=1)
        unoccluded = seen >= depth_l * 0.98 - 0.05
        return np.where(inside & unoccluded, disp, np.float32(np.nan)).astype(np.float32)

    def visibility(
        self, ids: npt.NDArray[np.int32], boxes: Packed, cam_pose: F64
    ) -> tuple[dict[int, int], dict[int, float]]:
        """Visible pixels per object, and their share of the object's whole projected area.

        The projected area counts what lies outside the image too (up to one image size beyond
        each border), sampled on a grid coarse enough to stay cheap for big objects.
        """
        counts = np.bincount(ids[ids >= 0].ravel(), minlength=1)
        pixels = {int(i): int(c) for i, c in enumerate(counts) if c > 0}
        fractions: dict[int, float] = {}
        w, h = self.rig.width, self.rig.height
        origin, rot = cam_pose[:3, 3], cam_pose[:3, :3]
        rects = boxes.screen_rects(origin, rot, self._intr, (-w, 2 * w, -h, 2 * h))
        for obj in pixels:
            index = np.flatnonzero(boxes.objs == obj)
            r = rects[index]
            r = r[(r[:, 1] > r[:, 0]) & (r[:, 3] > r[:, 2])]
            if len(r) == 0:
                continue
            x0, x1, y0, y1 = int(r[:, 0].min()), int(r[:, 1].max()), int(r[:, 2].min()), int(r[:, 3].max())
            step = max(1, math.ceil(math.sqrt((x1 - x0) * (y1 - y0) / 40000)))
            hits = raycast.coverage(boxes.take(index), origin, rot, self._intr, (x0, x1, y0, y1), step)
            area = float(hits * step * step)
            fractions[obj] = min(1.0, pixels[obj] / area) if area > 0 else 0.0
        return pixels, fractions
