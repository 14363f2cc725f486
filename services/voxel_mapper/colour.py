"""Colour spaces and the paper's similarity (Eq. 1) between a voxel and a cluster.

Colours are normalised to 0..1 in RGB and HSL (hue as a fraction of the circle), so the two
terms of Eq. 1 weigh alike: ``f(v, c) = ||RGB(v) - RGB(c)||_2 + ||HSL(v) - HSL(c)||_1``.
The functions are numba-compiled because the map update calls ``rgb_to_hsl`` once per point
and the flood fill calls ``similarity`` once per candidate neighbour.

Hue is an angle, and the hue of a grey is noise: asphalt, concrete and a grey wall give each
pixel an arbitrary hue. Read as a plain number (the default, as the paper writes Eq. 1), red at
0.02 and at 0.98 average to cyan and differ by nearly the whole circle. With ``circular`` hue is
averaged as a chroma vector (grey points add nothing; voxel_map.py) and Eq. 1's hue term goes the
short way round the circle. It is an option, off, because the rest of the pipeline was measured
with the plain reading: docs/results/voxel.md, "Session 36", has what it changes.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import numpy.typing as npt


@numba.njit(cache=True, inline="always")
def rgb_to_hsl(r: float, g: float, b: float) -> tuple[float, float, float]:
    """HSL of one RGB colour, all components in 0..1 (the usual hexcone definition)."""
    hi = max(r, g, b)
    lo = min(r, g, b)
    light = 0.5 * (hi + lo)
    d = hi - lo
    if d <= 0.0:
        return 0.0, 0.0, light
    sat = d / (1.0 - abs(2.0 * light - 1.0))
    if hi == r:
        hue = (g - b) / d
        if hue < 0.0:
            hue += 6.0
    elif hi == g:
        hue = (b - r) / d + 2.0
    else:
        hue = (r - g) / d + 4.0
    return hue / 6.0, min(sat, 1.0), light


@numba.njit(cache=True, inline="always")
def similarity(rgb_v: npt.NDArray[np.float64], hsl_v: npt.NDArray[np.float64],
               rgb_c: npt.NDArray[np.float64], hsl_c: npt.NDArray[np.float64], circular: bool = False) -> float:
    """Eq. 1: Euclidean distance in RGB plus Manhattan distance in HSL, on normalised means."""
    dr = rgb_v[0] - rgb_c[0]
    dg = rgb_v[1] - rgb_c[1]
    db = rgb_v[2] - rgb_c[2]
    d_hue = abs(hsl_v[0] - hsl_c[0])
    if circular:
        d_hue = min(d_hue, 1.0 - d_hue)
    l1 = d_hue + abs(hsl_v[1] - hsl_c[1]) + abs(hsl_v[2] - hsl_c[2])
    return np.sqrt(dr * dr + dg * dg + db * db) + l1


@numba.njit(cache=True, inline="always")
def hue_of(chroma_x: float | npt.NDArray[np.float64], chroma_y: float | npt.NDArray[np.float64]) -> Any:
    """The hue (0..1) of a summed chroma vector, or of arrays of them; 0 for a grey (a zero vector)."""
    return (np.arctan2(chroma_y, chroma_x) / (2.0 * np.pi)) % 1.0


def hue_and_spread(chroma: npt.NDArray[np.float64], weight: npt.NDArray[np.float64]) -> tuple[
        npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Mean hue and circular variance (both 0..1) from summed chroma vectors (n, 2) and their lengths (n,).

    The variance is one less the summed vector's length over the summed lengths: 0 when every
    coloured point has one hue, 1 when their hues cancel out (and for a grey, whose hue is no datum).
    """
    hue = hue_of(chroma[:, 0], chroma[:, 1])
    length = np.hypot(chroma[:, 0], chroma[:, 1])
    spread = np.where(weight > 0.0, 1.0 - length / np.maximum(weight, 1e-12), 1.0)
    return hue, np.clip(spread, 0.0, 1.0)


@numba.njit(cache=True)
def _hsl_rows(rgb: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    out = np.empty_like(rgb)
    for i in range(rgb.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = rgb_to_hsl(rgb[i, 0], rgb[i, 1], rgb[i, 2])
    return out


def hsl_of(rgb: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """HSL (0..1) of Nx3 RGB colours given as uint8 (0..255) or floats (0..1)."""
    arr = np.asarray(rgb)
    scaled = arr.astype(np.float64) / 255.0 if arr.dtype == np.uint8 else arr.astype(np.float64)
    return _hsl_rows(np.ascontiguousarray(scaled.reshape(-1, 3)))
