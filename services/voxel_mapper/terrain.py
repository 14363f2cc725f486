"""The ground under the voxels: the paper's flat road, or a terrain profile estimated per frame.

The paper clusters only voxels above a flat road (z > 0) and names terrain estimation as its most
important future work. ``TerrainProfile`` is a v-disparity-like estimate in the vehicle frame:
the road is the densest horizontal layer of points in each slice of distance ahead, so a
histogram of point heights per 1 m slice of x, searched from the vehicle outwards inside a band
around the height predicted from the slices already found (the origin is on the road), gives a
height profile g(x) that follows grades and crests. A slice without enough road points (an
occluding wall, the sky beyond a crest) continues the previous grade. Height above the road is
then z - g(x).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


class FlatGround:
    """The paper's assumption: the road is the plane z = 0 of the vehicle frame."""

    def fit(self, points: npt.NDArray[np.floating]) -> FlatGround:
        return self

    def height(self, points: npt.NDArray[np.floating]) -> F64:
        """Height above the road of vehicle-frame points."""
        return np.asarray(points[:, 2], dtype=np.float64)


@numba.njit(cache=True)
def _height_histogram(points: npt.NDArray[np.float32], x0: float, dx: float, nx: int,
                      z0: float, dz: float, nz: int) -> npt.NDArray[np.int64]:
    hist = np.zeros((nx, nz), dtype=np.int64)
    for p in range(points.shape[0]):
        i = int(np.floor((points[p, 0] - x0) / dx))
        k = int(np.floor((points[p, 2] - z0) / dz))
        if 0 <= i < nx and 0 <= k < nz:
            hist[i, k] += 1
    return hist


@dataclass
class TerrainProfile:
    """Road height g(x) ahead of the vehicle, from the densest layer of points per slice of x."""

    x_min: float = 0.0
    x_max: float = 28.7
    z_min: float = -1.0
    z_max: float = 3.5
    slice_m: float = 1.0  # extent of one slice of distance
    bin_m: float = 0.05  # height resolution of the histogram
    band_m: float = 0.25  # search band around the predicted height, at the first slice
    max_grade: float = 0.15  # steepest change of height per metre accepted
    min_points: int = 20  # fewer road points in a slice: keep the previous grade

    def __post_init__(self) -> None:
        self.nx = max(1, int(np.ceil((self.x_max - self.x_min) / self.slice_m)))
        self.nz = max(1, int(np.ceil((self.z_max - self.z_min) / self.bin_m)))
        self.xs = self.x_min + (np.arange(self.nx) + 0.5) * self.slice_m
        self.ground = np.zeros(self.nx)

    def fit(self, points: npt.NDArray[np.floating]) -> TerrainProfile:
        """Estimate g(x) from this frame's vehicle-frame points."""
        pts = np.ascontiguousarray(points, dtype=np.float32)
        hist = _height_histogram(pts, self.x_min, self.slice_m, self.nx, self.z_min, self.bin_m, self.nz)
        smooth = hist.astype(np.float64)
        smooth[:, 1:-1] = 0.25 * hist[:, :-2] + 0.5 * hist[:, 1:-1] + 0.25 * hist[:, 2:]
        centres = self.z_min + (np.arange(self.nz) + 0.5) * self.bin_m
        x_prev, g_prev, grade = 0.0, 0.0, 0.0
        for i, x in enumerate(self.xs):
            step = x - x_prev
            predicted = g_prev + grade * step
            half = self.band_m + self.max_grade * step
            lo = max(0, int((predicted - half - self.z_min) / self.bin_m))
            hi = min(self.nz, int(np.ceil((predicted + half - self.z_min) / self.bin_m)) + 1)
            window = smooth[i, lo:hi]
            if hi > lo and window.max() * 4.0 / 3.0 >= self.min_points:
                peak = lo + int(np.argmax(window))
                near = slice(max(0, peak - 2), min(self.nz, peak + 3))
                weights = hist[i, near]
                height = float(weights @ centres[near] / max(weights.sum(), 1))
                new_grade = np.clip((height - g_prev) / step, grade - self.max_grade, grade + self.max_grade)
                grade = float(np.clip(new_grade, -self.max_grade, self.max_grade))
                g_prev, x_prev = g_prev + grade * step, x
                self.ground[i] = g_prev
            else:
                self.ground[i] = predicted
        return self

    def height(self, points: npt.NDArray[np.floating]) -> F64:
        """Height above the estimated road of vehicle-frame points."""
        pts = np.asarray(points, dtype=np.float64)
        road = np.interp(pts[:, 0], np.concatenate(([0.0], self.xs)), np.concatenate(([0.0], self.ground)))
        return pts[:, 2] - road
