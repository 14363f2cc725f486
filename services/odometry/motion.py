"""Camera motion between two stereo frames: RANSAC over 3-point samples, Levenberg-Marquardt.

The motion ``T`` maps points of the previous camera frame into the current one. It is the pose
that minimises the reprojection error of the previous frame's triangulated points in BOTH current
images (StereoScan). Every solver here is batched over hypotheses: all RANSAC samples are solved
at once with a few vectorised Gauss-Newton steps instead of a Python loop per sample.

Increments are left-multiplicative, ``T <- exp(delta) T`` with ``delta = (w, v)``, so the
Jacobian of a transformed point P is ``[-[P]x | I]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

#: points every RANSAC hypothesis is scored on (the winner is then checked against all points).
SCORE_POINTS = 200
#: refinement rounds on the inliers, each re-selecting them (and re-weighting, when robust).
ROUNDS = 3


@dataclass(frozen=True)
class Rig:
    """What projection needs of a rectified stereo rig."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float


@dataclass(frozen=True)
class MotionEstimate:
    """Result of :func:`estimate_motion`: motion, inlier mask and 6x6 covariance of (w, v)."""

    motion: F64
    inliers: npt.NDArray[np.bool_]
    covariance: F64
    rms_px: float


def triangulate(obs: F64, rig: Rig) -> F64:
    """3D points (camera frame) from observations (u_left, v_left, u_right, v_right)."""
    disparity = obs[:, 0] - obs[:, 2]
    z = rig.fx * rig.baseline / disparity
    x = (obs[:, 0] - rig.cx) * z / rig.fx
    y = (0.5 * (obs[:, 1] + obs[:, 3]) - rig.cy) * z / rig.fy
    return np.stack([x, y, z], axis=-1)


def so3_exp(w: F64) -> F64:
    """Rotation matrices of rotation vectors (..., 3) -> (..., 3, 3) (Rodrigues)."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = np.zeros((*w.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2] = -w[..., 2], w[..., 1]
    k[..., 1, 0], k[..., 1, 2] = w[..., 2], -w[..., 0]
    k[..., 2, 0], k[..., 2, 1] = -w[..., 1], w[..., 0]
    small = theta < 1e-9
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1.0 - np.cos(safe)) / (safe * safe))
    return np.eye(3) + a * k + b * (k @ k)


def project(points: F64, rig: Rig) -> F64:
    """(..., N, 3) camera points -> (..., N, 4) predicted (u_left, v_left, u_right, v_right)."""
    inv_z = 1.0 / points[..., 2]
    u = rig.fx * points[..., 0] * inv_z + rig.cx
    v = rig.fy * points[..., 1] * inv_z + rig.cy
    return np.stack([u, v, u - rig.fx * rig.baseline * inv_z, v], axis=-1)


def _apply(motion: F64, points: F64) -> F64:
    """(K, 4, 4) motions applied to (K, N, 3) points."""
    return points @ np.swapaxes(motion[:, :3, :3], 1, 2) + motion[:, None, :3, 3]


def _apply_inverse(motion: F64, points: F64) -> F64:
    """Inverses of (K, 4, 4) motions applied to (K, N, 3) points."""
    return (points - motion[:, None, :3, 3]) @ motion[:, :3, :3]


@dataclass(frozen=True)
class Problem:
    """Points seen in one frame and their observations in the other, K x N each.

    Forward: previous points moved by the motion into the current images. Backward: current
    points moved by the inverse motion into the previous images; adding it cancels, to first
    order, the depth bias that noisy disparities give triangulated points (they lie too far on
    average, which alone makes a forward-only estimate travel too far).
    """

    points: F64
    obs: F64
    weights: F64
    backward: bool = False

    def take(self, mask: npt.NDArray[np.bool_]) -> Problem:
        """The points of a single problem (K = 1) that ``mask`` selects."""
        return Problem(self.points[:, mask], self.obs[:, mask], self.weights[:, mask], self.backward)

    def moved(self, motion: F64) -> F64:
        return _apply_inverse(motion, self.points) if self.backward else _apply(motion, self.points)


def _jacobian(motion: F64, problem: Problem, rig: Rig) -> tuple[F64, F64]:
    """Residuals (K x N x 4) and their Jacobian (K x N x 4 x 6) w.r.t. a left increment (w, v)."""
    p = problem.moved(motion)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    inv_z = 1.0 / np.where(np.abs(z) < 1e-6, 1e-6, z)
    res = project(p, rig) - problem.obs
    fz, gz = rig.fx * inv_z, rig.fy * inv_z
    zero = np.zeros_like(fz)
    du = np.stack([fz, zero, -fz * x * inv_z], axis=-1)
    dv = np.stack([zero, gz, -gz * y * inv_z], axis=-1)
    dur = du.copy()
    dur[..., 2] = -fz * (x - rig.baseline) * inv_z
    dp = np.stack([du, dv, dur, dv], axis=-2)  # d(pixel)/dP: K x N x 4 x 3
    if problem.backward:
        # P = R^T (X - t - w x X - v): dP/dw = R^T [X]x, dP/dv = -R^T
        dp = dp @ motion[:, None, :3, :3].swapaxes(-1, -2)
        src = problem.points
        sx, sy, sz = src[..., 0:1], src[..., 1:2], src[..., 2:3]
        jw = -np.stack(
            [dp[..., 2] * sy - dp[..., 1] * sz, dp[..., 0] * sz - dp[..., 2] * sx, dp[..., 1] * sx - dp[..., 0] * sy],
            axis=-1,
        )
        return res, np.concatenate([jw, -dp], axis=-1)
    # P = R X + t + w x P + v: column i of dP/dw is e_i x P
    xe, ye, ze = x[..., None], y[..., None], z[..., None]
    jw = np.stack(
        [dp[..., 2] * ye - dp[..., 1] * ze, dp[..., 0] * ze - dp[..., 2] * xe, dp[..., 1] * xe - dp[..., 0] * ye],
        axis=-1,
    )
    return res, np.concatenate([jw, dp], axis=-1)


def _system(motion: F64, problems: list[Problem], rig: Rig) -> tuple[F64, F64, float]:
    """Gauss-Newton normal equations summed over problems, and the weighted squared residual."""
    h = np.zeros((motion.shape[0], 6, 6))
    g = np.zeros((motion.shape[0], 6, 1))
    total = 0.0
    for problem in problems:
        res, jac = _jacobian(motion, problem, rig)
        jac = jac.reshape(motion.shape[0], -1, 6)
        r = res.reshape(motion.shape[0], -1, 1)
        wj = jac * np.repeat(problem.weights, 4, axis=-1)[..., None]
        h += wj.swapaxes(1, 2) @ jac
        g += wj.swapaxes(1, 2) @ r
        total += float((res * res * problem.weights[..., None]).sum())
    return h, g, total


def _step(motion: F64, delta: F64) -> F64:
    update = np.zeros_like(motion)
    update[:, :3, :3] = so3_exp(delta[:, :3])
    update[:, :3, 3] = delta[:, 3:]
    update[:, 3, 3] = 1.0
    return update @ motion


def _cost(motion: F64, problems: list[Problem], rig: Rig) -> F64:
    cost = np.zeros(motion.shape[0])
    for problem in problems:
        res = project(problem.moved(motion), rig) - problem.obs
        cost += ((res * res).sum(axis=-1) * problem.weights).sum(axis=-1)
    return np.where(np.isfinite(cost), cost, np.inf)


def solve(motion: F64, problems: list[Problem], rig: Rig, iterations: int) -> F64:
    """Levenberg-Marquardt on K motions at once, each with its own points (K x N x 3)."""
    damping = np.full(motion.shape[0], 1e-3)
    cost = _cost(motion, problems, rig)
    for _ in range(iterations):
        h, g, _ = _system(motion, problems, rig)
        diag = np.diagonal(h, axis1=1, axis2=2)
        lhs = h + (damping[:, None] * diag + 1e-9)[:, :, None] * np.eye(6)
        delta = -np.linalg.solve(lhs, g)[..., 0]
        trial = _step(motion, delta)
        trial_cost = _cost(trial, problems, rig)
        better = trial_cost < cost
        motion = np.where(better[:, None, None], trial, motion)
        cost = np.where(better, trial_cost, cost)
        damping = np.where(better, damping * 0.1, damping * 10.0)
        if np.all(np.abs(delta) < 1e-9):
            break
    return motion


def reprojection_sq(motion: F64, problem: Problem, rig: Rig) -> F64:
    """Squared reprojection error (both images) of every point of ``problem`` under K motions."""
    moved = problem.moved(motion)
    res = project(moved, rig) - problem.obs
    err = (res * res).sum(axis=-1)
    return np.where((moved[..., 2] <= 0.0) | ~np.isfinite(err), np.inf, err)


def _samples(n: int, count: int, rng: np.random.Generator) -> npt.NDArray[np.intp]:
    """``count`` random triples of distinct indices below n."""
    return rng.random((count, n)).argpartition(3, axis=1)[:, :3]


def estimate_motion(
    previous: F64,
    current: F64,
    weights: F64,
    rig: Rig,
    prior: F64,
    iterations: int,
    threshold_px: float,
    rng: np.random.Generator,
    symmetric: bool = True,
    robust_px: float = 0.0,
) -> MotionEstimate | None:
    """RANSAC of 3-point Gauss-Newton solutions, then LM on all inliers (twice, re-selecting them).

    ``previous``, ``current``: N x 4 observations (u_l, v_l, u_r, v_r) of the same points;
    ``prior``: start of every minimal solve (the expected motion, or identity). With
    ``symmetric`` the refinement also reprojects current points into the previous images.
    None when fewer than 3 points remain.
    """
    n = len(previous)
    if n < 3:
        return None
    thr2 = threshold_px * threshold_px
    forward = Problem(triangulate(previous, rig)[None], current[None], weights[None])
    problems = [forward]
    if symmetric:
        problems.append(Problem(triangulate(current, rig)[None], previous[None], weights[None], backward=True))
    idx = _samples(n, iterations, rng)
    sample = Problem(forward.points[0][idx], forward.obs[0][idx], np.ones((iterations, 3)))
    hyps = solve(np.repeat(prior[None], iterations, axis=0), [sample], rig, iterations=6)
    hyps = np.concatenate([hyps, prior[None]])
    # hypotheses are ranked on a fixed random subset: the ranking needs a few hundred points, not all
    probe = rng.permutation(n)[:SCORE_POINTS]
    errors = reprojection_sq(hyps, Problem(forward.points[:, probe], forward.obs[:, probe], weights[None, probe]), rig)
    motion = hyps[int(np.argmax((errors < thr2).sum(axis=1)))][None]
    inliers = reprojection_sq(motion, forward, rig)[0] < thr2
    chosen = problems
    for _ in range(ROUNDS):
        if inliers.sum() < 3:
            return None
        chosen = [p.take(inliers) for p in problems]
        if robust_px > 0:  # Cauchy weights: marginal inliers pull less than clean ones
            err = np.sum([reprojection_sq(motion, p, rig)[0] for p in chosen], axis=0)
            chosen = [Problem(p.points, p.obs, p.weights / (1.0 + err / robust_px**2), p.backward) for p in chosen]
        motion = solve(motion, chosen, rig, 12)
        inliers = np.all([reprojection_sq(motion, p, rig)[0] < thr2 for p in problems], axis=0)
    if inliers.sum() < 3:
        return None
    chosen = [p.take(inliers) for p in problems]
    h, _, total = _system(motion, chosen, rig)
    dof = max(4 * len(chosen) * int(inliers.sum()) - 6, 1)
    sigma2 = total / dof
    try:
        cov = np.linalg.inv(h[0]) * sigma2
    except np.linalg.LinAlgError:
        cov = np.full((6, 6), np.inf)
    return MotionEstimate(motion=motion[0], inliers=inliers, covariance=cov, rms_px=float(np.sqrt(sigma2)))
