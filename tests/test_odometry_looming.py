"""Temporal matches refined with the window warped by the expected motion (services/odometry/looming.py)."""

from __future__ import annotations

import numpy as np
from test_odometry import BASE, C2V, F, H, W, cam_motion, render

from common.geometry import invert
from services.odometry.looming import plane_jacobians, track_warped
from services.odometry.motion import Rig
from services.odometry.subpixel import track

RIG = Rig(fx=F, fy=F, cx=W / 2, cy=H / 2, baseline=BASE)
CAMERA_HEIGHT = 1.65  # the corridor's floor, y = 1.65 m in the camera frame (y down)
STEP_M = 1.5


def _road_pixels() -> tuple[np.ndarray, np.ndarray]:
    """Previous-left pixels on the floor 6-12 m ahead, and their right-image matches."""
    us, vs = np.meshgrid(np.arange(140.0, 341.0, 20.0), np.arange(H / 2 + 55.0, H / 2 + 111.0, 8.0))
    left = np.c_[us.ravel(), vs.ravel()]
    depth = CAMERA_HEIGHT * F / (left[:, 1] - H / 2)
    return left, left - np.c_[F * BASE / depth, np.zeros(len(left))]


def _projected(left: np.ndarray, motion: np.ndarray) -> np.ndarray:
    depth = CAMERA_HEIGHT * F / (left[:, 1] - H / 2)
    points = np.c_[(left[:, 0] - W / 2) / F, (left[:, 1] - H / 2) / F, np.ones(len(left))] * depth[:, None]
    moved = points @ motion[:3, :3].T + motion[:3, 3]
    return np.c_[F * moved[:, 0] / moved[:, 2] + W / 2, F * moved[:, 1] / moved[:, 2] + H / 2]


def test_a_point_facing_the_camera_grows_by_its_depth_ratio() -> None:
    motion = invert(cam_motion(0.0, (0.0, 0.0, 2.0)))  # previous camera coordinates -> current
    left = np.array([[300.0, 150.0]])  # above the horizon: a surface facing the camera
    right = left - np.array([[F * BASE / 10.0, 0.0]])  # 10 m away
    jac = plane_jacobians(left, right, motion, RIG, C2V, 0.3)[0]
    np.testing.assert_allclose(jac, np.eye(2) * 10.0 / 8.0, atol=1e-9)


def test_the_road_map_matches_the_floor_seen_one_step_later() -> None:
    motion = invert(cam_motion(0.0, (0.0, 0.0, STEP_M)))
    left, right = _road_pixels()
    jac = plane_jacobians(left, right, motion, RIG, C2V, 0.3)
    eps = 0.5
    columns = []
    for shift in (np.array([eps, 0.0]), np.array([0.0, eps])):
        columns.append((_projected(left + shift, motion) - _projected(left - shift, motion)) / (2 * eps))
    numeric = np.stack(columns, axis=2)
    np.testing.assert_allclose(jac, numeric, rtol=1e-3, atol=1e-3)
    assert np.all(jac[:, 1, 1] > 1.15)  # the floor stretches down the image: what a square window misses


def test_floor_features_are_found_where_they_project_and_a_square_window_is_not() -> None:
    """Rendered corridor, 1.5 m forward: the floor 6-12 m ahead grows 14-33 % across and more down the image."""
    pose = cam_motion(0.0, (0.0, 0.0, STEP_M))
    previous = render(np.eye(4))[..., 0]
    current = render(pose)[..., 0]
    motion = invert(pose)
    left, right = _road_pixels()
    truth = _projected(left, motion)
    guess = (truth + np.array([0.6, -0.5])).astype(np.float32)  # where the matched corner was detected
    jac = plane_jacobians(left, right, motion, RIG, C2V, 0.3)
    warped, ok = track_warped(previous, current, left.astype(np.float32), guess, jac, 11, 2.0)
    square, ok_square = track(previous, current, left.astype(np.float32), guess, 11, 2.0)
    assert ok.mean() > 0.9
    error = np.linalg.norm(warped[ok] - truth[ok], axis=1)
    error_square = np.linalg.norm(square[ok_square] - truth[ok_square], axis=1)
    assert np.median(error) < 0.2  # 0.12 px measured; a square window: 0.94 px, and 27 % lost
    assert np.median(error) < 0.3 * np.median(error_square)


def test_nothing_to_track_and_windows_off_the_image() -> None:
    image = render(np.eye(4))[..., 0]
    empty = np.zeros((0, 2), np.float32)
    out, ok = track_warped(image, image, empty, empty, np.zeros((0, 2, 2)), 11, 2.0)
    assert out.shape == (0, 2) and ok.shape == (0,)
    corner = np.array([[2.0, 3.0], [240.0, 200.0]], np.float32)
    out, ok = track_warped(image, image, corner, corner, np.repeat(np.eye(2)[None], 2, axis=0), 11, 2.0)
    assert ok.tolist() == [False, True]  # the corner's window leaves the image
    np.testing.assert_allclose(out[1], corner[1], atol=0.05)  # no motion: stays put
