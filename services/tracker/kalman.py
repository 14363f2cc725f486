"""The paper's linear Kalman filter on a 6-D centroid state, batched over every track at once.

State per track: ``[x, y, z, vx, vy, vz]`` in the world frame, constant velocity, the centroid
position measured. The maths is filterpy's ``KalmanFilter`` (same predict, same Joseph-form
update), written over a leading track axis because a per-track filterpy call costs ~40 µs and a
frame may hold dozens of tracks; ``tests/test_tracker.py`` checks the two agree. The loops over
tracks are compiled: numpy's batched products of 6 x 6 matrices cost more in dispatch than in
arithmetic, a fifth of the tracker's time with 50 tracks (docs/results/tracking.md, "Session 30").
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
BOOL = npt.NDArray[np.bool_]

#: the measurement picks the position out of the state.
H: F64 = np.hstack([np.eye(3), np.zeros((3, 3))])


def transition(dt: float) -> F64:
    """Constant-velocity transition over ``dt`` seconds."""
    f = np.eye(6)
    f[0:3, 3:6] = np.eye(3) * dt
    return f


def process_noise(dt: float, accel_std: F64) -> F64:
    """Discrete white-noise acceleration per axis (filterpy's ``Q_discrete_white_noise``, dim 2).

    ``accel_std`` holds one acceleration standard deviation per axis: the road keeps obstacles on
    the ground, so the vertical one is much smaller than the horizontal ones.
    """
    var = np.asarray(accel_std, dtype=np.float64) ** 2
    q = np.zeros((6, 6))
    q[0:3, 0:3] = np.diag(var * dt**4 / 4.0)
    q[0:3, 3:6] = np.diag(var * dt**3 / 2.0)
    q[3:6, 0:3] = q[0:3, 3:6]
    q[3:6, 3:6] = np.diag(var * dt**2)
    return q


class ProcessNoise:
    """A car's process noise and, if set, a person's, over a time step; kept between frames.

    A stream has one or two time steps, and building the two matrices afresh each frame cost 17 µs
    of the tracker's 2 ms (docs/results/tracking.md, "Session 56").
    """

    def __init__(self, accel_std: F64, upright_accel_std: F64 | None = None) -> None:
        self.accel_std, self.upright_accel_std = accel_std, upright_accel_std
        self._kept: dict[float, tuple[F64, F64 | None]] = {}

    def over(self, dt: float) -> tuple[F64, F64 | None]:
        """The two (6, 6) matrices over ``dt`` seconds; the second None without a person's noise."""
        if dt not in self._kept:
            if len(self._kept) > 16:  # a stream with jittery stamps: the store stays small
                self._kept.clear()
            upright = None if self.upright_accel_std is None else process_noise(dt, self.upright_accel_std)
            self._kept[dt] = (process_noise(dt, self.accel_std), upright)
        return self._kept[dt]


def initial_covariance(position_cov: F64, velocity_var: F64) -> F64:
    """Covariances (n, 6, 6) of tracks born from one cluster each: position as measured, velocity unknown."""
    out = np.zeros((len(position_cov), 6, 6))
    out[:, 0:3, 0:3] = position_cov
    idx = np.arange(3, 6)
    out[:, idx, idx] = velocity_var
    return out


def _per_track(m: F64, n: int, shape: tuple[int, int]) -> F64:
    """``m`` as one contiguous matrix per track: a shared (a, b) matrix repeated, an (n, a, b) stack kept."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(m, dtype=np.float64), (n, *shape)))


def predict(x: F64, p: F64, f: F64, q: F64) -> tuple[F64, F64]:
    """Predict ``n`` states ``x`` (n, 6) and covariances ``p`` (n, 6, 6) through ``f`` with noise ``q``
    ((6, 6), or (n, 6, 6) per track)."""
    n = x.shape[0]
    return _predict(np.ascontiguousarray(x), np.ascontiguousarray(p), np.ascontiguousarray(f), _per_track(q, n, (6, 6)))


def normalised_innovation(x: F64, p: F64, z: F64, r: F64) -> F64:
    """Squared innovation over its predicted covariance, per measured dimension (n,): 1 when consistent."""
    n = x.shape[0]
    return _innovation(
        np.ascontiguousarray(x), np.ascontiguousarray(p), np.ascontiguousarray(z), _per_track(r, n, (3, 3))
    )


def update(x: F64, p: F64, z: F64, r: F64) -> tuple[F64, F64]:
    """Correct ``n`` states with position measurements ``z`` (n, 3) of covariance ``r`` (3, 3) or (n, 3, 3).

    Joseph form, as filterpy: it keeps ``p`` symmetric positive definite in float64 however
    small the measurement noise.
    """
    n = x.shape[0]
    return _update(np.ascontiguousarray(x), np.ascontiguousarray(p), np.ascontiguousarray(z), _per_track(r, n, (3, 3)))


@numba.njit(cache=True)
def _inverse3(a: F64) -> F64:
    """The inverse of a 3 x 3 matrix by its cofactors (a covariance here, never singular)."""
    out = np.empty((3, 3))
    out[0, 0] = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    out[0, 1] = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
    out[0, 2] = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    out[1, 0] = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    out[1, 1] = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
    out[1, 2] = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
    out[2, 0] = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    out[2, 1] = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
    out[2, 2] = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    det = a[0, 0] * out[0, 0] + a[0, 1] * out[1, 0] + a[0, 2] * out[2, 0]
    return out / det


@numba.njit(cache=True)
def _predict(x: F64, p: F64, f: F64, q: F64) -> tuple[F64, F64]:
    n = x.shape[0]
    x_new, p_new = np.empty_like(x), np.empty_like(p)
    fp = np.empty((6, 6))
    for t in range(n):
        for i in range(6):
            acc = 0.0
            for j in range(6):
                acc += f[i, j] * x[t, j]
            x_new[t, i] = acc
        for i in range(6):
            for j in range(6):
                acc = 0.0
                for k in range(6):
                    acc += f[i, k] * p[t, k, j]
                fp[i, j] = acc
        for i in range(6):
            for j in range(6):
                acc = 0.0
                for k in range(6):
                    acc += fp[i, k] * f[j, k]
                p_new[t, i, j] = acc + q[t, i, j]
    return x_new, p_new


@numba.njit(cache=True)
def _innovation(x: F64, p: F64, z: F64, r: F64) -> F64:
    n = x.shape[0]
    out = np.empty(n)
    y = np.empty(3)
    for t in range(n):
        s_inv = _inverse3(p[t, 0:3, 0:3] + r[t])
        for i in range(3):
            y[i] = z[t, i] - x[t, i]
        acc = 0.0
        for i in range(3):
            for j in range(3):
                acc += y[i] * s_inv[i, j] * y[j]
        out[t] = acc / 3.0
    return out


@numba.njit(cache=True)
def _product(a: F64, b: F64, out: F64) -> None:
    """``out = a @ b`` for square matrices, written out: numba's ``@`` allocates a result per call."""
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for m in range(n):
                acc += a[i, m] * b[m, j]
            out[i, j] = acc


@numba.njit(cache=True)
def _update(x: F64, p: F64, z: F64, r: F64) -> tuple[F64, F64]:
    n = x.shape[0]
    x_new, p_new = np.empty_like(x), np.empty_like(p)
    k = np.empty((6, 3))
    i_kh = np.empty((6, 6))
    a = np.empty((6, 6))
    kr = np.empty((6, 3))
    for t in range(n):
        s_inv = _inverse3(p[t, 0:3, 0:3] + r[t])
        for i in range(6):  # K = P H^T S^-1
            for j in range(3):
                acc = 0.0
                for m in range(3):
                    acc += p[t, i, m] * s_inv[m, j]
                k[i, j] = acc
        for i in range(6):  # x + K (z - H x)
            acc = x[t, i]
            for j in range(3):
                acc += k[i, j] * (z[t, j] - x[t, j])
            x_new[t, i] = acc
        for i in range(6):  # I - K H
            for j in range(6):
                i_kh[i, j] = (1.0 if i == j else 0.0) - (k[i, j] if j < 3 else 0.0)
        _product(i_kh, p[t], a)  # (I - K H) P
        for i in range(6):  # K R
            for j in range(3):
                acc = 0.0
                for m in range(3):
                    acc += k[i, m] * r[t, m, j]
                kr[i, j] = acc
        for i in range(6):  # (I - K H) P (I - K H)^T + K R K^T
            for j in range(6):
                acc = 0.0
                for m in range(6):
                    acc += a[i, m] * i_kh[j, m]
                for m in range(3):
                    acc += kr[i, m] * k[j, m]
                p_new[t, i, j] = acc
    return x_new, p_new


def correct_velocity(x: F64, p: F64, rows: I64, v: F64, std: F64, gate: float) -> BOOL:
    """Correct the states ``rows`` in place with horizontal velocity measurements ``v`` (m, 2) of
    standard deviation ``std`` (m,; both axes alike); which were corrected.

    A measurement whose squared innovation over its covariance (2 dimensions) exceeds ``gate`` is
    left out: it measures something else than the track follows. Joseph form, as ``update``.
    """
    done = np.zeros(len(rows), dtype=np.bool_)
    if len(rows):
        _velocity(x, p, np.asarray(rows, dtype=np.int64), np.ascontiguousarray(v, dtype=np.float64),
                  np.ascontiguousarray(std, dtype=np.float64), float(gate), done)  # fmt: skip
    return done


@numba.njit(cache=True)
def _velocity(x: F64, p: F64, rows: I64, v: F64, std: F64, gate: float, done: BOOL) -> None:
    k = np.empty((6, 2))
    i_kh = np.empty((6, 6))
    a = np.empty((6, 6))
    for i in range(rows.shape[0]):
        t, r = rows[i], std[i] * std[i]
        s00, s01, s10, s11 = p[t, 3, 3] + r, p[t, 3, 4], p[t, 4, 3], p[t, 4, 4] + r
        det = s00 * s11 - s01 * s10
        i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
        y0, y1 = v[i, 0] - x[t, 3], v[i, 1] - x[t, 4]
        if not y0 * (i00 * y0 + i01 * y1) + y1 * (i10 * y0 + i11 * y1) <= gate:
            continue
        done[i] = True
        for m in range(6):  # K = P H^T S^-1
            k[m, 0] = p[t, m, 3] * i00 + p[t, m, 4] * i10
            k[m, 1] = p[t, m, 3] * i01 + p[t, m, 4] * i11
        for m in range(6):
            x[t, m] += k[m, 0] * y0 + k[m, 1] * y1
        for m in range(6):  # I - K H
            for j in range(6):
                i_kh[m, j] = (1.0 if m == j else 0.0) - (k[m, 0] if j == 3 else (k[m, 1] if j == 4 else 0.0))
        _product(i_kh, p[t], a)  # (I - K H) P
        for m in range(6):  # (I - K H) P (I - K H)^T + K R K^T
            for j in range(6):
                acc = r * (k[m, 0] * k[j, 0] + k[m, 1] * k[j, 1])
                for q in range(6):
                    acc += a[m, q] * i_kh[j, q]
                p[t, m, j] = acc
