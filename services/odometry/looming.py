"""The temporal leg refined with the previous patch warped as the expected motion warps its surface.

Lucas-Kanade as OpenCV runs it moves a square window without deforming it. Between two frames
the road a few metres ahead grows by 10-30 %, and more down the image: with the true motion,
features in the bottom third of synthetic urban-s1's image were still 0.7-1.0 px from where they
project, against 0.13 px above the horizon, so the robust refinement weighed the nearest,
best-placed points least. Here each feature's window is mapped into the current image by the local affine map of
the plane it lies on under the predicted motion: the road for points within ``ground_m`` of
it, otherwise a plane facing the camera at the point's depth. Only the translation is then
solved for. With it those road features sit 0.3 px from their projection, and r_err fell on every
synthetic urban and crossing run measured (docs/results/odometry.md, "Session 16").

The stereo legs keep OpenCV's tracker: two views of one instant see a surface at one scale.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from services.odometry.motion import Rig

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

ITERATIONS = 20
CONVERGED_PX = 0.01


def plane_jacobians(left: F64, right: F64, motion: F64, rig: Rig, cam_to_vehicle: F64, ground_m: float) -> F64:
    """N x 2 x 2 local maps of previous-left pixels into the current left image under ``motion``.

    ``left``, ``right``: N x 2 matched positions in the previous pair (their disparity gives the
    depth); ``motion`` takes previous camera coordinates to current ones. The plane through each
    point induces the homography ``K (R + t n^T / d) K^-1``; its Jacobian at the pixel is the map.
    """
    k = np.array([[rig.fx, 0.0, rig.cx], [0.0, rig.fy, rig.cy], [0.0, 0.0, 1.0]])
    k_inv = np.linalg.inv(k)
    rot, t = motion[:3, :3], motion[:3, 3]
    depth = rig.fx * rig.baseline / np.maximum(left[:, 0] - right[:, 0], 0.5)
    rays = np.c_[(left[:, 0] - rig.cx) / rig.fx, (left[:, 1] - rig.cy) / rig.fy, np.ones(len(left))]
    points = rays * depth[:, None]
    up, height = cam_to_vehicle[2, :3], cam_to_vehicle[2, 3]  # road: up . X + height = 0
    road = points @ up + height < ground_m
    normals = np.where(road[:, None], -up[None, :], np.array([0.0, 0.0, 1.0])[None, :])
    offsets = np.where(road, height, depth)  # n . X = offset on the plane
    homographies = (k @ rot @ k_inv)[None] + np.einsum("i,nj->nij", k @ t, normals @ k_inv) / offsets[:, None, None]
    pixels = np.c_[left, np.ones(len(left))]
    mapped = np.einsum("nij,nj->ni", homographies, pixels)
    w = mapped[:, 2]
    x, y = mapped[:, 0] / w, mapped[:, 1] / w
    jac = np.empty((len(left), 2, 2))
    jac[:, 0, :] = (homographies[:, 0, :2] - x[:, None] * homographies[:, 2, :2]) / w[:, None]
    jac[:, 1, :] = (homographies[:, 1, :2] - y[:, None] * homographies[:, 2, :2]) / w[:, None]
    return jac


def _sums(values: F32) -> F64:
    return values.sum(axis=1, dtype=np.float64)


def track_warped(
    source: npt.NDArray[np.uint8],
    target: npt.NDArray[np.uint8],
    source_xy: F32,
    guess_xy: F32,
    jacobians: F64,
    window: int,
    max_shift: float,
) -> tuple[F32, npt.NDArray[np.bool_]]:
    """Target positions of source windows mapped by ``jacobians``, and which converged near their guess.

    Gauss-Newton on the translation alone, all features at once: each step samples the target
    at the mapped window (bilinear) and solves the 2 x 2 normal equations per feature.
    """
    n = len(source_xy)
    if n == 0:
        return guess_xy.copy(), np.zeros(0, dtype=bool)
    half = window // 2
    steps = np.arange(-half, half + 1, dtype=np.float64)
    dx, dy = (a.ravel() for a in np.meshgrid(steps, steps))
    src = source.astype(np.float32)
    tgt = target.astype(np.float32)
    grad_x = cv2.Sobel(tgt, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    grad_y = cv2.Sobel(tgt, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    sx = np.asarray(source_xy, dtype=np.float64)
    template = cv2.remap(src, (sx[:, :1] + dx).astype(np.float32), (sx[:, 1:] + dy).astype(np.float32),
                         cv2.INTER_LINEAR)  # fmt: skip
    off_x = jacobians[:, 0, :1] * dx + jacobians[:, 0, 1:] * dy
    off_y = jacobians[:, 1, :1] * dx + jacobians[:, 1, 1:] * dy
    at = np.asarray(guess_xy, dtype=np.float64).copy()
    solvable = np.ones(n, dtype=bool)
    active = np.arange(n)  # features still moving by more than CONVERGED_PX a step
    for _ in range(ITERATIONS):
        ox, oy = off_x[active], off_y[active]
        map_x = (at[active, :1] + ox).astype(np.float32)
        map_y = (at[active, 1:] + oy).astype(np.float32)
        error = cv2.remap(tgt, map_x, map_y, cv2.INTER_LINEAR) - template[active]
        gx = cv2.remap(grad_x, map_x, map_y, cv2.INTER_LINEAR)
        gy = cv2.remap(grad_y, map_x, map_y, cv2.INTER_LINEAR)
        a, b, c = _sums(gx * gx), _sums(gx * gy), _sums(gy * gy)
        ex, ey = _sums(gx * error), _sums(gy * error)
        det = a * c - b * b
        ok = det > 1e-6
        solvable[active[~ok]] = False
        det = np.where(ok, det, 1.0)
        step = np.where(ok[:, None], -np.c_[c * ex - b * ey, a * ey - b * ex] / det[:, None], 0.0)
        at[active] += step
        active = active[ok & (np.abs(step).max(axis=1) >= CONVERGED_PX)]
        if active.size == 0:
            break
    rows, cols = target.shape[:2]
    reach = np.abs(off_x).max(1) + 1.0, np.abs(off_y).max(1) + 1.0
    inside = (at[:, 0] >= reach[0]) & (at[:, 0] <= cols - 1 - reach[0])
    inside &= (at[:, 1] >= reach[1]) & (at[:, 1] <= rows - 1 - reach[1])
    inside &= (sx[:, 0] >= half) & (sx[:, 0] <= source.shape[1] - 1 - half)
    inside &= (sx[:, 1] >= half) & (sx[:, 1] <= source.shape[0] - 1 - half)
    ok = solvable & inside & (np.abs(at - guess_xy).max(axis=1) <= max_shift)
    return at.astype(np.float32), ok
