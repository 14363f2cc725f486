"""The ground under the voxels: the paper's flat road, or a terrain profile estimated per frame.

The paper clusters only voxels above a flat road (z > 0) and names terrain estimation as its most
important future work. ``TerrainProfile`` is a v-disparity-like estimate in the vehicle frame,
g(x, y) = g(x) + c * y: the road is the densest thin layer of points in each slice of distance
ahead, so a histogram of point heights per 1 m slice of x, searched from the vehicle outwards in
a band around the last road height found (the origin is on the road; the band widens by the
steepest grade accepted per metre), gives a profile g(x) that follows grades and crests. A slice
without enough road points (an occluding wall, the dead ground beyond a crest) is interpolated
between its neighbours, or keeps the last height beyond the farthest. The cross slope c (road
camber, camera roll: 6 cm/m on KITTI raw 0009 with a level camera model) is a least-squares fit
of the residual heights of the points near that profile, after which the profile is found again.
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
def _drawn(
    points: npt.NDArray[np.float32], every: int, rarer: int
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """About one point in ``every``, and one in ``every * rarer`` of those, drawn by each point's own
    coordinates (mm): the draw does not change with whatever other points the cloud holds.

    Sampling every n-th point by index made the fit depend on unrelated points: on KITTI tracking
    0001 two voxels of sky left out shifted which road points were drawn, the road at 38 m moved,
    and a parked car dropped below the clearance (docs/results/voxel.md, "Session 19").
    """
    n = points.shape[0]
    drawn = np.empty((n + 1, 3), dtype=np.float32)
    few = np.empty((n + 1, 3), dtype=np.float32)
    m = k = 0
    for p in range(n):  # branch-free: a coin-flip branch per point costs more than the copies
        h = (np.int64(points[p, 0] * 1000.0) * 73856093) ^ (np.int64(points[p, 1] * 1000.0) * 19349663)
        h ^= np.int64(points[p, 2] * 1000.0) * 83492791
        h = ((h ^ (h >> 13)) * 2654435761) >> 7
        chosen = (h & 0xFFFF) * every < 0x10000
        rare = chosen & (((h >> 16) & 0xFFFF) * rarer < 0x10000)
        for a in range(3):
            drawn[m, a] = points[p, a]
            few[k, a] = points[p, a]
        m += chosen
        k += rare
    return drawn[:m], few[:k]


@numba.njit(cache=True)
def _height_histogram(
    points: npt.NDArray[np.float32], cross: float, x0: float, dx: float, nx: int, z0: float, dz: float, nz: int
) -> npt.NDArray[np.int64]:
    """Counts of points per (slice of x, bin of z - cross * y)."""
    hist = np.zeros((nx, nz), dtype=np.int64)
    for p in range(points.shape[0]):
        i = int(np.floor((points[p, 0] - x0) / dx))
        k = int(np.floor((points[p, 2] - cross * points[p, 1] - z0) / dz))
        if 0 <= i < nx and 0 <= k < nz:
            hist[i, k] += 1
    return hist


@dataclass
class TerrainProfile:
    """Road height g(x) + c * y ahead of the vehicle, from the densest layer of points per slice."""

    x_min: float = 0.0
    x_max: float = 28.7
    z_min: float = -1.0
    z_max: float = 3.5
    slice_m: float = 1.0  # extent of one slice of distance
    bin_m: float = 0.05  # height resolution of the histogram
    band_m: float = 0.25  # search band around the last road height found
    max_grade: float = 0.15  # steepest change of height per metre accepted
    max_cross: float = 0.12  # steepest cross slope accepted
    min_points: int = 10  # fewer (histogrammed) road points in a slice: interpolated
    stride: int = 2  # one point in n makes the histograms (far slices keep ~200 road points)
    sample: int = 8  # one point in n fits the cross slope

    def __post_init__(self) -> None:
        self.nx = max(1, int(np.ceil((self.x_max - self.x_min) / self.slice_m)))
        self.nz = max(1, int(np.ceil((self.z_max - self.z_min) / self.bin_m)))
        self.xs = self.x_min + (np.arange(self.nx) + 0.5) * self.slice_m
        self.ground = np.zeros(self.nx)
        self.cross = 0.0

    def fit(self, points: npt.NDArray[np.floating]) -> TerrainProfile:
        """Estimate g(x) and the cross slope from this frame's vehicle-frame points."""
        pts = np.ascontiguousarray(points, dtype=np.float32)
        drawn, few = _drawn(pts, self.stride, max(1, self.sample // self.stride))
        self.cross = 0.0
        self._profile(drawn)
        self.cross = self._cross_slope(few)
        self._profile(drawn)
        return self

    def height(self, points: npt.NDArray[np.floating]) -> F64:
        """Height above the estimated road of vehicle-frame points."""
        pts = np.asarray(points, dtype=np.float64)
        road = np.interp(pts[:, 0], np.concatenate(([0.0], self.xs)), np.concatenate(([0.0], self.ground)))
        return pts[:, 2] - road - self.cross * pts[:, 1]

    def _profile(self, pts: npt.NDArray[np.float32]) -> None:
        hist = _height_histogram(pts, self.cross, self.x_min, self.slice_m, self.nx, self.z_min, self.bin_m, self.nz)
        smooth = hist.astype(np.float64)
        smooth[:, 1:-1] = 0.25 * hist[:, :-2] + 0.5 * hist[:, 1:-1] + 0.25 * hist[:, 2:]
        centres = self.z_min + (np.arange(self.nz) + 0.5) * self.bin_m
        found = np.zeros(self.nx, dtype=bool)
        x_prev, g_prev = 0.0, 0.0
        for i, x in enumerate(self.xs):
            reach = self.max_grade * (x - x_prev)
            lo = max(0, int((g_prev - self.band_m - reach - self.z_min) / self.bin_m))
            hi = min(self.nz, int(np.ceil((g_prev + self.band_m + reach - self.z_min) / self.bin_m)) + 1)
            if hi <= lo or smooth[i, lo:hi].max() * 4.0 / 3.0 < self.min_points:
                continue
            peak = lo + int(np.argmax(smooth[i, lo:hi]))
            near = slice(max(0, peak - 2), min(self.nz, peak + 3))
            height = float(np.sum(hist[i, near] * centres[near]) / max(hist[i, near].sum(), 1))
            g_prev, x_prev = float(np.clip(height, g_prev - reach, g_prev + reach)), x
            self.ground[i], found[i] = g_prev, True
        self.ground = np.interp(self.xs, self.xs[found], self.ground[found]) if found.any() else np.zeros(self.nx)

    def _cross_slope(self, pts: npt.NDArray[np.float32]) -> float:
        """Least-squares c in z - g(x) = c * y + d over points near the road, twice, narrowing."""
        y = pts[:, 1].astype(np.float64)
        resid = self.height(pts)
        cross, offset = 0.0, 0.0
        for band in (0.4, 0.15):
            near = np.abs(resid - cross * y - offset) < band
            if np.count_nonzero(near) < 3 * self.min_points or np.ptp(y[near]) < 2.0:
                break
            yn, rn = y[near], resid[near]
            ym, rm = yn.mean(), rn.mean()
            dy = yn - ym  # sums, not BLAS dot products: BLAS threads stall on a loaded machine
            cross = float(np.sum(dy * (rn - rm)) / max(float(np.sum(dy * dy)), 1e-9))
            offset = rm - cross * ym
        return float(np.clip(cross, -self.max_cross, self.max_cross))
