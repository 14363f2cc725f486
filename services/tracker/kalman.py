"""The paper's linear Kalman filter on a 6-D centroid state, batched over every track at once.

State per track: ``[x, y, z, vx, vy, vz]`` in the world frame, constant velocity, the centroid
position measured. The maths is filterpy's ``KalmanFilter`` (same predict, same Joseph-form
update), written over a leading track axis because a per-track filterpy call costs ~40 µs and a
frame may hold dozens of tracks; ``tests/test_tracker.py`` checks the two agree.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

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


def initial_covariance(position_cov: F64, velocity_var: F64) -> F64:
    """Covariances (n, 6, 6) of tracks born from one cluster each: position as measured, velocity unknown."""
    out = np.zeros((len(position_cov), 6, 6))
    out[:, 0:3, 0:3] = position_cov
    idx = np.arange(3, 6)
    out[:, idx, idx] = velocity_var
    return out


def predict(x: F64, p: F64, f: F64, q: F64) -> tuple[F64, F64]:
    """Predict ``n`` states ``x`` (n, 6) and covariances ``p`` (n, 6, 6) through ``f`` with noise ``q``."""
    x_new = x @ f.T
    p_new = f @ p @ f.T + q
    return x_new, p_new


def normalised_innovation(x: F64, p: F64, z: F64, r: F64) -> F64:
    """Squared innovation over its predicted covariance, per measured dimension (n,): 1 when consistent."""
    y = z - x[:, 0:3]
    s = p[:, 0:3, 0:3] + r
    return np.einsum("ni,ni->n", y, np.linalg.solve(s, y[:, :, None])[:, :, 0]) / 3.0


def update(x: F64, p: F64, z: F64, r: F64) -> tuple[F64, F64]:
    """Correct ``n`` states with position measurements ``z`` (n, 3) of covariance ``r`` (3, 3) or (n, 3, 3).

    Joseph form, as filterpy: it keeps ``p`` symmetric positive definite in float64 however
    small the measurement noise.
    """
    y = z - x[:, 0:3]
    pht = p[:, :, 0:3]  # P H^T
    s = pht[:, 0:3, :] + r  # H P H^T + R
    k = pht @ np.linalg.inv(s)  # (n, 6, 3)
    x_new = x + np.einsum("nij,nj->ni", k, y)
    i_kh = np.eye(6) - k @ H
    p_new = i_kh @ p @ np.swapaxes(i_kh, 1, 2) + k @ r @ np.swapaxes(k, 1, 2)
    return x_new, p_new
