"""Ray casting of boxes into per-pixel buffers (the ground is cast first, by ``ground``).

One ray per pixel with camera-frame direction ``((u - cx)/fx, (v - cy)/fy, 1)``, so the ray
parameter of a hit is directly the camera depth Z. Boxes are tested only inside the screen
rectangle their corners project to, which is what keeps a scene of a hundred boxes fast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numba import njit

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]

NEAR = 0.05
CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
SUN = np.array([-0.35, 0.45, 0.82]) / np.linalg.norm([-0.35, 0.45, 0.82])


@dataclass
class Buffers:
    """Flat per-pixel results of one view: depth (inf = sky), surface, object, texture coordinates."""

    depth: F32
    surface: I32  # -1 = sky
    obj: I32  # ground-truth object id, -1 = ground or sky
    u: F32
    v: F32
    footprint: F32  # metres one pixel covers on the surface
    light: F32
    paint: F32  # road marking coverage 0..1


@dataclass(frozen=True)
class Box:
    """One box in the world this frame, with the ids the buffers record for it."""

    center: F64
    rotation: F64  # box axes in world (columns)
    half: F64
    surface: int
    obj: int

    def face_light(self) -> F32:
        """Lambert light of the six faces, ordered (axis, sign -, +)."""
        normals = np.concatenate([-self.rotation.T, self.rotation.T], axis=0)[[0, 3, 1, 4, 2, 5]]
        return (0.55 + 0.45 * np.clip(normals @ SUN, 0.0, None)).astype(np.float32)


@dataclass(frozen=True)
class Packed:
    """Boxes as flat arrays, the form the compiled kernels take."""

    centers: F64
    rotations: F64
    halves: F64
    surfaces: I32
    objs: I32
    lights: F32

    @staticmethod
    def of(boxes: list[Box]) -> Packed:
        if not boxes:
            z = np.zeros((0, 3))
            return Packed(z, np.zeros((0, 3, 3)), z, np.zeros(0, np.int32), np.zeros(0, np.int32),
                          np.zeros((0, 6), np.float32))
        return Packed(
            np.array([b.center for b in boxes]), np.array([b.rotation for b in boxes]),
            np.array([b.half for b in boxes]), np.array([b.surface for b in boxes], np.int32),
            np.array([b.obj for b in boxes], np.int32), np.array([b.face_light() for b in boxes]),
        )

    def take(self, index: npt.NDArray[np.int64]) -> Packed:
        return Packed(self.centers[index], self.rotations[index], self.halves[index], self.surfaces[index],
                      self.objs[index], self.lights[index])

    def screen_rects(self, cam_pos: F64, cam_rot: F64, intr: tuple[float, float, float, float],
                     bounds: tuple[int, int, int, int]) -> npt.NDArray[np.int64]:
        """Pixel rectangles (x0, x1, y0, y1) each box can cover inside ``bounds``; empty where none."""
        fx, fy, cx, cy = intr
        bx0, bx1, by0, by1 = bounds
        corners = self._corners()
        local = (corners - cam_pos) @ cam_rot
        z = local[..., 2]
        front = z >= NEAR
        zs = np.where(front, z, 1.0)
        us = fx * local[..., 0] / zs + cx
        vs = fy * local[..., 1] / zs + cy
        rects = np.stack([
            np.floor(us.min(axis=1)) - 1, np.ceil(us.max(axis=1)) + 2,
            np.floor(vs.min(axis=1)) - 1, np.ceil(vs.max(axis=1)) + 2,
        ], axis=1)
        partial = ~front.all(axis=1)
        rects[partial] = (bx0, bx1, by0, by1)
        rects = np.clip(rects, [bx0, bx0, by0, by0], [bx1, bx1, by1, by1]).astype(np.int64)
        empty = (rects[:, 0] >= rects[:, 1]) | (rects[:, 2] >= rects[:, 3]) | ~front.any(axis=1)
        rects[empty] = (0, 0, 0, 0)
        return rects

    def _corners(self) -> F64:
        """(B, 8, 3) world corners."""
        local = CORNERS[None, :, :] * self.halves[:, None, :]
        return self.centers[:, None, :] + np.einsum("bij,bkj->bki", self.rotations, local)


@njit(cache=True, nogil=True)
def _slab(o: F64, dl: F64, half: F64) -> tuple[float, int]:  # pragma: no cover - compiled
    """Entry parameter and entry axis of a ray (local frame) into a box; (inf, -1) on a miss."""
    tn, tf, axis = -np.inf, np.inf, -1
    for k in range(3):
        if dl[k] != 0.0:
            t1 = (-half[k] - o[k]) / dl[k]
            t2 = (half[k] - o[k]) / dl[k]
            lo, hi = min(t1, t2), max(t1, t2)
            if lo > tn:
                tn, axis = lo, k
            tf = min(tf, hi)
        elif abs(o[k]) > half[k]:
            return np.inf, -1
    if axis < 0 or tf < tn or tn <= NEAR:
        return np.inf, -1
    return tn, axis


@njit(cache=True, nogil=True)
def _into_box(o, rot, origin, center):  # pragma: no cover - compiled
    """The ray origin in the box's own frame, into ``o``."""
    for k in range(3):
        o[k] = rot[0, k] * (origin[0] - center[0]) + rot[1, k] * (origin[1] - center[1]) \
            + rot[2, k] * (origin[2] - center[2])


@njit(cache=True, nogil=True)
def _record_hit(i, b, o, dl, t, axis, surfaces, objs, lights, fx,
                depth, surface, obj, u, v, footprint, light, paint):  # pragma: no cover - compiled
    """Write box ``b``'s hit at ray parameter ``t`` (entry face ``axis``) into ray ``i`` of the buffers."""
    p0, p1, p2 = o[0] + t * dl[0], o[1] + t * dl[1], o[2] + t * dl[2]
    if axis == 0:
        u[i], v[i] = p1, p2
    elif axis == 1:
        u[i], v[i] = p0 + 3.1, p2
    else:
        u[i], v[i] = p0 + 6.2, p1
    cos = abs(dl[axis]) / np.sqrt(dl[0] ** 2 + dl[1] ** 2 + dl[2] ** 2)
    depth[i] = t
    surface[i] = surfaces[b]
    obj[i] = objs[b]
    footprint[i] = t / fx / np.sqrt(max(cos, 0.05))
    light[i] = lights[b, axis * 2 + (1 if dl[axis] < 0 else 0)]
    paint[i] = 0.0


@njit(cache=True, nogil=True)
def _cast_boxes(dirs, width, origin, centers, rots, halves, rects, surfaces, objs, lights, fx,
                depth, surface, obj, u, v, footprint, light, paint):  # pragma: no cover - compiled
    o = np.empty(3)
    dl = np.empty(3)
    for b in range(len(centers)):
        rot = rots[b]
        _into_box(o, rot, origin, centers[b])
        x0, x1, y0, y1 = rects[b]
        for y in range(y0, y1):
            for x in range(x0, x1):
                i = y * width + x
                for k in range(3):
                    dl[k] = rot[0, k] * dirs[i, 0] + rot[1, k] * dirs[i, 1] + rot[2, k] * dirs[i, 2]
                t, axis = _slab(o, dl, halves[b])
                if axis < 0 or t >= depth[i]:
                    continue
                _record_hit(i, b, o, dl, t, axis, surfaces, objs, lights, fx, depth, surface, obj, u, v, footprint,
                            light, paint)


def cast_boxes(buf: Buffers, boxes: Packed, rects: npt.NDArray[np.int64], origin: F64, dirs: F32,
               width: int, fx: float) -> None:
    """Draw boxes into the buffers inside their screen rectangles, nearest surface winning (a z-buffer)."""
    _cast_boxes(dirs, width, origin.astype(np.float64), boxes.centers, boxes.rotations, boxes.halves, rects,
                boxes.surfaces, boxes.objs, boxes.lights, fx, buf.depth, buf.surface, buf.obj, buf.u, buf.v,
                buf.footprint, buf.light, buf.paint)


@njit(cache=True, nogil=True)
def _cast_boxes_at(dirs, xs, ys, origin, centers, rots, halves, rects, surfaces, objs, lights, fx,
                   depth, surface, obj, u, v, footprint, light, paint):  # pragma: no cover - compiled
    o = np.empty(3)
    dl = np.empty(3)
    for b in range(len(centers)):
        x0, x1, y0, y1 = rects[b]
        first, stop = np.searchsorted(ys, y0), np.searchsorted(ys, y1)
        if first >= stop:
            continue
        rot = rots[b]
        _into_box(o, rot, origin, centers[b])
        for i in range(first, stop):
            if xs[i] < x0 or xs[i] >= x1:
                continue
            for k in range(3):
                dl[k] = rot[0, k] * dirs[i, 0] + rot[1, k] * dirs[i, 1] + rot[2, k] * dirs[i, 2]
            t, axis = _slab(o, dl, halves[b])
            if axis < 0 or t >= depth[i]:
                continue
            _record_hit(i, b, o, dl, t, axis, surfaces, objs, lights, fx, depth, surface, obj, u, v, footprint, light,
                        paint)


def cast_boxes_at(buf: Buffers, boxes: Packed, rects: npt.NDArray[np.int64], origin: F64, dirs: F32,
                  xs: npt.NDArray[np.int64], ys: npt.NDArray[np.int64], fx: float) -> None:
    """As :func:`cast_boxes` for a list of rays, each inside pixel (``xs``, ``ys``); ``ys`` ascending."""
    _cast_boxes_at(dirs, xs, ys, origin.astype(np.float64), boxes.centers, boxes.rotations, boxes.halves, rects,
                   boxes.surfaces, boxes.objs, boxes.lights, fx, buf.depth, buf.surface, buf.obj, buf.u, buf.v,
                   buf.footprint, buf.light, buf.paint)


@njit(cache=True, nogil=True)
def _coverage(origin, cam_rot, intr, rect, step, centers, rots, halves):  # pragma: no cover - compiled
    fx, fy, cx, cy = intr
    x0, x1, y0, y1 = rect
    o = np.empty((len(centers), 3))
    for b in range(len(centers)):
        for k in range(3):
            o[b, k] = rots[b, 0, k] * (origin[0] - centers[b, 0]) + rots[b, 1, k] * (origin[1] - centers[b, 1]) \
                + rots[b, 2, k] * (origin[2] - centers[b, 2])
    dl = np.empty(3)
    count = 0
    for y in range(y0, y1, step):
        for x in range(x0, x1, step):
            a, c = (x - cx) / fx, (y - cy) / fy
            d0 = cam_rot[0, 0] * a + cam_rot[0, 1] * c + cam_rot[0, 2]
            d1 = cam_rot[1, 0] * a + cam_rot[1, 1] * c + cam_rot[1, 2]
            d2 = cam_rot[2, 0] * a + cam_rot[2, 1] * c + cam_rot[2, 2]
            for b in range(len(centers)):
                for k in range(3):
                    dl[k] = rots[b, 0, k] * d0 + rots[b, 1, k] * d1 + rots[b, 2, k] * d2
                if _slab(o[b], dl, halves[b])[1] >= 0:
                    count += 1
                    break
    return count


def coverage(boxes: Packed, origin: F64, cam_rot: F64, intr: tuple[float, float, float, float],
             rect: tuple[int, int, int, int], step: int) -> int:
    """Pixels (sampled every ``step``) of ``rect`` that see any of the boxes, ignoring everything else."""
    return int(_coverage(origin.astype(np.float64), cam_rot.astype(np.float64), np.asarray(intr, np.float64),
                         np.asarray(rect, np.int64), step, boxes.centers, boxes.rotations, boxes.halves))
