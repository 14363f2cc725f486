"""Ray casting of the ground: road with its markings, kerb faces, raised sidewalks and verges.

The road surface follows the height profile exactly (piecewise-linear planes); beyond the kerb
line the surface is raised by the kerb height, and a ray that passes the kerb line between the
two heights meets the kerb's face, found by bisection on the lateral road coordinate.
"""

from __future__ import annotations

import numpy as np

from common.scenarios.raycast import F32, F64, Buffers
from common.scenarios.road import Road

#: surface indices of the ground; boxes are numbered after these.
ASPHALT, SIDEWALK, KERB, VERGE = 0, 1, 2, 3


def cast_ground(road: Road, origin: F64, dirs: F32, fx: float) -> Buffers:
    """Road, kerb faces, sidewalks and verges for every ray; rays above the horizon see sky."""
    n = len(dirs)
    buf = Buffers(
        depth=np.full(n, np.inf, np.float32),
        surface=np.full(n, -1, np.int32),
        obj=np.full(n, -1, np.int32),
        u=np.zeros(n, np.float32),
        v=np.zeros(n, np.float32),
        footprint=np.ones(n, np.float32),
        light=np.ones(n, np.float32),
        paint=np.zeros(n, np.float32),
    )
    t = road.intersect(origin, dirs)
    hit = np.flatnonzero(np.isfinite(t))
    px = origin[0] + t[hit] * dirs[hit, 0]
    py = origin[1] + t[hit] * dirs[hit, 1]
    _, d = road.to_road(px, py)
    on_road = np.abs(d) <= road.half_width
    road_idx = hit[on_road]
    buf.depth[road_idx] = t[road_idx]
    buf.surface[road_idx] = ASPHALT
    buf.u[road_idx], buf.v[road_idx] = px[on_road], py[on_road]
    # beyond the kerb line: the raised sidewalk, or the kerb's face if the ray meets it first
    off = hit[~on_road]
    t_top = road.intersect(origin, dirs[off], lift=road.kerb_height)
    top_ok = np.isfinite(t_top)
    tx = origin[0] + t_top * dirs[off, 0]
    ty = origin[1] + t_top * dirs[off, 1]
    _, d_top = road.to_road(np.where(top_ok, tx, 0.0), np.where(top_ok, ty, 0.0))
    top = top_ok & (np.abs(d_top) > road.half_width)
    top_idx = off[top]
    buf.depth[top_idx] = t_top[top]
    buf.surface[top_idx] = np.where(np.abs(d_top[top]) > road.half_width + road.sidewalk, VERGE, SIDEWALK)
    buf.u[top_idx], buf.v[top_idx] = tx[top], ty[top]
    face_idx = off[~top]
    lo = np.where(top_ok[~top], t_top[~top], 0.0)
    hi = t[face_idx].copy()
    for _ in range(14):
        mid = (lo + hi) / 2
        _, dm = road.to_road(origin[0] + mid * dirs[face_idx, 0], origin[1] + mid * dirs[face_idx, 1])
        beyond = np.abs(dm) > road.half_width
        hi = np.where(beyond, mid, hi)
        lo = np.where(beyond, lo, mid)
    buf.depth[face_idx] = hi
    buf.surface[face_idx] = KERB
    fs, _ = road.to_road(origin[0] + hi * dirs[face_idx, 0], origin[1] + hi * dirs[face_idx, 1])
    buf.u[face_idx] = fs
    buf.v[face_idx] = origin[2] + hi * dirs[face_idx, 2]
    buf.light[face_idx] = 0.8
    # footprint: lateral size over the square root of the slant, enough to stop lateral aliasing
    norm = np.linalg.norm(dirs, axis=1)
    slant = np.sqrt(np.clip(np.abs(dirs[:, 2]) / norm, 0.02, 1.0))
    buf.footprint = (buf.depth / fx / np.where(buf.surface == KERB, 1.0, slant)).astype(np.float32)
    ground = buf.surface == ASPHALT
    gs, gd = road.to_road(buf.u[ground].astype(np.float64), buf.v[ground].astype(np.float64))
    buf.paint[ground] = road.marking_weight(gs, gd, buf.footprint[ground].astype(np.float64))
    return buf
