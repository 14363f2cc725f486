"""Greedy association of the paper's Algorithm IV-C.1 over a weighted, vectorised distance.

The distance between track ``t`` and cluster ``c`` is the linear combination the paper names:

    d = w_position * ||p_t - p_c||_2                          (metres, predicted centroid)
      + w_color    * (||RGB_t - RGB_c||_2 + ||HSL_t - HSL_c||_1)   (Eq. 1 of the clustering, hue circular)
      + w_size     * ||e_t - e_c||_1 / (||e_t||_1 + ||e_c||_1)     (box extents, relative: 0..1)
      + w_density  * |rho_t - rho_c|                             (voxels / box volume: 0..1)

Colour reuses the clustering's own similarity so one threshold scale covers both stages; size is
relative so a pedestrian and a building are judged alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Weights:
    """Weights of the four distance terms and the threshold a pair must stay under."""

    position: float
    color: float
    size: float
    density: float
    gate: float


def color_distance(rgb_t: NDArray, hsl_t: NDArray, rgb_c: NDArray, hsl_c: NDArray) -> NDArray:
    """Eq. 1 between every track (rows) and every cluster (columns); hue wraps around at 1."""
    d_rgb = np.linalg.norm(rgb_t[:, None, :] - rgb_c[None, :, :], axis=2)
    d_hsl = np.abs(hsl_t[:, None, :] - hsl_c[None, :, :])
    d_hsl[..., 0] = np.minimum(d_hsl[..., 0], 1.0 - d_hsl[..., 0])
    return d_rgb + d_hsl.sum(axis=2)


def distance_matrix(
    weights: Weights,
    position_t: NDArray,
    rgb_t: NDArray,
    hsl_t: NDArray,
    extent_t: NDArray,
    density_t: NDArray,
    position_c: NDArray,
    rgb_c: NDArray,
    hsl_c: NDArray,
    extent_c: NDArray,
    density_c: NDArray,
) -> NDArray:
    """(tracks x clusters) weighted distances."""
    d_pos = np.linalg.norm(position_t[:, None, :] - position_c[None, :, :], axis=2)
    e_t, e_c = extent_t[:, None, :], extent_c[None, :, :]
    total = np.abs(e_t).sum(axis=2) + np.abs(e_c).sum(axis=2)
    d_size = np.abs(e_t - e_c).sum(axis=2) / np.maximum(total, 1e-9)
    d_density = np.abs(density_t[:, None] - density_c[None, :])
    return (
        weights.position * d_pos
        + weights.color * color_distance(rgb_t, hsl_t, rgb_c, hsl_c)
        + weights.size * d_size
        + weights.density * d_density
    )


def greedy_pairs(distance: NDArray, gate: float) -> tuple[NDArray, NDArray]:
    """Algorithm IV-C.1: repeatedly take the smallest remaining pair while it is under ``gate``.

    Taking pairs in ascending order of distance and skipping those whose track or cluster is
    already taken is the same as re-running the arg-min after each removal, without the T*C
    passes. Returns matched (track rows, cluster columns).
    """
    n_t, n_c = distance.shape
    if n_t == 0 or n_c == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    flat = np.flatnonzero(distance < gate)
    order = flat[np.argsort(distance.ravel()[flat], kind="stable")]
    rows, cols = np.divmod(order, n_c)
    row_used = np.zeros(n_t, dtype=bool)
    col_used = np.zeros(n_c, dtype=bool)
    out_t: list[int] = []
    out_c: list[int] = []
    limit = min(n_t, n_c)
    for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
        if row_used[r] or col_used[c]:
            continue
        row_used[r] = col_used[c] = True
        out_t.append(r)
        out_c.append(c)
        if len(out_t) == limit:
            break
    return np.asarray(out_t, dtype=np.int64), np.asarray(out_c, dtype=np.int64)
