"""The road: a centreline (straight, then an optional arc), a height profile, kerbs and markings.

Everything on the road is placed in road coordinates (s along the centreline, d to its left),
so moving traffic follows the curve and the ego's yaw rate comes from the road itself. The
height profile is a function of world x (piecewise linear), which is what lets ``slope`` break
the flat-road assumption while staying exact to ray-cast.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
Arr = npt.NDArray[np.floating]


@dataclass(frozen=True)
class Marking:
    """A painted line at lateral offset ``d``; dashed when ``period`` > 0 (``on`` metres painted)."""

    d: float
    half_width: float = 0.075
    period: float = 0.0
    on: float = 3.0


@dataclass(frozen=True)
class Zebra:
    """A pedestrian crossing: stripes across the road between ``s_start`` and ``s_end``."""

    s_start: float
    s_end: float
    stripe: float = 0.5


@dataclass(frozen=True)
class Road:
    """Road geometry in the world frame (the ego's vehicle frame at frame 0)."""

    y0: float  # world y of the centreline along its straight part
    half_width: float = 6.0
    sidewalk: float = 2.5
    kerb_height: float = 0.12
    curve_start: float = math.inf  # s where the arc begins
    radius: float = math.inf  # signed: positive turns left
    profile_x: tuple[float, ...] = (0.0,)
    profile_z: tuple[float, ...] = (0.0,)
    markings: tuple[Marking, ...] = ()
    zebras: tuple[Zebra, ...] = field(default_factory=tuple)

    # ------------------------------------------------------------------ centreline

    def to_world(self, s: Arr, d: Arr) -> tuple[F64, F64, F64]:
        """World x, y and heading of road coordinates (vectorised)."""
        s = np.asarray(s, np.float64)
        d = np.asarray(d, np.float64)
        x = s.copy()
        y = self.y0 + d
        heading = np.zeros_like(s)
        if math.isfinite(self.curve_start):
            arc = s > self.curve_start
            r = self.radius
            phi = (s[arc] - self.curve_start) / r
            cx, cy = self.curve_start, self.y0 + r
            x[arc] = cx + (r - d[arc]) * np.sin(phi)
            y[arc] = cy - (r - d[arc]) * np.cos(phi)
            heading[arc] = phi
        return x, y, heading

    def to_road(self, x: Arr, y: Arr) -> tuple[Arr, Arr]:
        """Road coordinates (s, d) of world points; continuous where the arc begins."""
        s = np.array(x, copy=True)
        d = y - self.y0
        if math.isfinite(self.curve_start):
            arc = x > self.curve_start
            r = self.radius
            qx = x[arc] - self.curve_start
            qy = y[arc] - (self.y0 + r)
            sign = 1.0 if r > 0 else -1.0
            phi = np.arctan2(sign * qx, -sign * qy)
            s[arc] = self.curve_start + r * phi
            d[arc] = r - sign * np.hypot(qx, qy)
        return s, d

    # ------------------------------------------------------------------ height

    def height(self, x: Arr) -> F64:
        """Road surface height at world x (flat beyond the profile's ends)."""
        return np.interp(x, self.profile_x, self.profile_z)

    def ground_z(self, x: Arr, d: Arr) -> F64:
        """Height of the surface an object stands on: the road, or the raised sidewalk."""
        lift = np.where(np.abs(d) > self.half_width, self.kerb_height, 0.0)
        return self.height(x) + lift

    def intersect(self, origin: F64, dirs: Arr, lift: float = 0.0) -> Arr:
        """Ray parameter of the first hit with the height profile raised by ``lift`` (inf: none)."""
        ox, _, oz = origin
        dx, dz = dirs[:, 0], dirs[:, 2]
        xs = np.asarray(self.profile_x, np.float64)
        zs = np.asarray(self.profile_z, np.float64) + lift
        best = np.full(len(dirs), np.inf, dirs.dtype)
        # segments: flat before, linear pieces, flat after
        pieces = [(-np.inf, xs[0], zs[0], 0.0)]
        for i in range(len(xs) - 1):
            b = (zs[i + 1] - zs[i]) / (xs[i + 1] - xs[i])
            pieces.append((xs[i], xs[i + 1], zs[i] - b * xs[i], b))
        pieces.append((xs[-1], np.inf, zs[-1], 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            for lo, hi, a, b in pieces:
                t = (a + b * ox - oz) / (dz - b * dx)
                hx = ox + t * dx
                ok = (t > 0) & (hx >= lo) & (hx <= hi) & (t < best)
                best = np.where(ok, t, best)
        return best

    def marking_weight(self, s: Arr, d: Arr, footprint: Arr) -> Arr:
        """Share of a pixel covered by paint, smoothed by its footprint so far lines do not alias."""
        fp = np.maximum(footprint, 1e-3)
        weight = np.zeros_like(s)
        for m in self.markings:
            lateral = np.clip((m.half_width - np.abs(d - m.d)) / fp + 0.5, 0.0, 1.0)
            if m.period > 0:
                phase = np.mod(s, m.period) - m.on / 2
                lateral = lateral * np.clip((m.on / 2 - np.abs(phase)) / fp + 0.5, 0.0, 1.0)
            weight = np.maximum(weight, lateral)
        for z in self.zebras:
            inside = np.clip((np.minimum(s - z.s_start, z.s_end - s)) / fp + 0.5, 0.0, 1.0)
            stripe = np.clip((z.stripe / 2 - np.abs(np.mod(d, 2 * z.stripe) - z.stripe)) / fp + 0.5, 0.0, 1.0)
            road = np.abs(d) < self.half_width - 0.3
            weight = np.maximum(weight, inside * stripe * road)
        return weight
