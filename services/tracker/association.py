"""Greedy association of the paper's Algorithm IV-C.1 over a weighted, vectorised distance.

The distance between track ``t`` and cluster ``c`` is the linear combination the paper names:

    d = w_position * ||p_t - p_c||_2 / sigma_tc               (standard deviations, predicted centroid)
      + w_color    * (||RGB_t - RGB_c||_2 + ||HSL_t - HSL_c||_1)   (Eq. 1 of the clustering, hue circular)
      + w_size     * ||e_t - e_c||_1 / (||e_t||_1 + ||e_c||_1)     (box extents, relative: 0..1)
      + w_density  * |rho_t - rho_c|                             (voxels / box volume: 0..1)

Colour reuses the clustering's own similarity so one threshold scale covers both stages; size is
relative so a pedestrian and a building are judged alike. Position is measured in standard
deviations of the pair's predicted offset (the track's position uncertainty plus the cluster's
measurement noise), and a pair further than ``position_gate`` of them is never associated: a
settled track does not hop to the next fragment of a hedge 2 m away however alike it looks, while
a young or long-unseen one, whose position is uncertain, may still be found far from where it was.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial.distance import cdist

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Weights:
    """Weights of the four distance terms and the threshold a pair must stay under."""

    position: float
    color: float
    size: float
    density: float
    gate: float
    position_gate: float  # standard deviations


def color_distance(rgb_t: NDArray, hsl_t: NDArray, rgb_c: NDArray, hsl_c: NDArray) -> NDArray:
    """Eq. 1 between every track (rows) and every cluster (columns); hue wraps around at 1.

    The hue of a grey is noise (asphalt, concrete and glass flip between any two hues from frame to
    frame), so the hue difference counts in proportion to the lesser of the two saturations.
    """
    d_hue = np.abs(hsl_t[:, None, 0] - hsl_c[None, :, 0])
    d_hue = np.minimum(d_hue, 1.0 - d_hue) * np.minimum(hsl_t[:, None, 1], hsl_c[None, :, 1])
    return cdist(rgb_t, rgb_c) + d_hue + cdist(hsl_t[:, 1:3], hsl_c[:, 1:3], "cityblock")


def position_variance(
    position_cov_t: NDArray, noise_scale_t: NDArray, extent_t: NDArray, r_c: NDArray, extent_c: NDArray
) -> NDArray:
    """(tracks x clusters) variance per axis of the offset between predicted and measured centroid.

    Isotropic (a third of the traces) to keep it a cheap matrix: the track's predicted position
    covariance, plus the cluster's measurement covariance and the change of box extent between
    them, both scaled by the track's adaptive noise factor.
    """
    p_t = np.trace(position_cov_t, axis1=1, axis2=2) / 3.0
    r = np.trace(r_c, axis1=1, axis2=2) / 3.0
    extent_change = cdist(extent_t, extent_c, "sqeuclidean") / 3.0
    return p_t[:, None] + noise_scale_t[:, None] * (r[None, :] + extent_change)


def distance_matrix(
    weights: Weights,
    position_var: NDArray,
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
    if len(position_t) == 0 or len(position_c) == 0:
        return np.zeros((len(position_t), len(position_c)))
    total = np.abs(extent_t).sum(axis=1)[:, None] + np.abs(extent_c).sum(axis=1)[None, :]
    d_size = cdist(extent_t, extent_c, "cityblock") / np.maximum(total, 1e-9)
    d_density = np.abs(density_t[:, None] - density_c[None, :])
    d_position = cdist(position_t, position_c) / np.sqrt(position_var)
    total = (
        weights.position * d_position
        + weights.color * color_distance(rgb_t, hsl_t, rgb_c, hsl_c)
        + weights.size * d_size
        + weights.density * d_density
    )
    total[d_position > weights.position_gate] = np.inf
    return total


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
    row_used = [False] * n_t  # lists: a numpy element access per pair costs more than the loop
    col_used = [False] * n_c
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
