"""Tracker core (step 5): greedy association, queues, Kalman filter, moving labels, bad input."""

from __future__ import annotations

import colorsys
import dataclasses
import subprocess

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from common.codec import decode, encode
from common.config import Config
from common.geometry import make_pose, rot_z
from common.messages import Cluster, Clusters, EgoMotion, Obstacle, Obstacles
from services.tracker import Tracker, kalman
from services.tracker import anchor as anchor_module
from services.tracker.against import REPO, compare
from services.tracker.anchor import SELECT_MAX, _kth, _order, anchors
from services.tracker.association import Weights, distance_matrix, greedy_pairs, position_variance
from services.tracker.fragments import Sight, Standing, components, footprint, gather, in_contact, merge, near_boxes
from services.tracker.left_behind import LeftBehind
from services.tracker.measurement import cut_covariance
from services.tracker.motion_window import speed_bounds
from services.tracker.observations import observe

EDGE = 0.25
PERIOD_NS = 100_000_000


def cluster(
    cid: int,
    centre: tuple[float, float, float] | np.ndarray,
    size: tuple[float, float, float] = (1.0, 1.0, 1.5),
    rgb: tuple[float, float, float] = (0.6, 0.2, 0.2),
    density: float = 0.5,
) -> Cluster:
    """A box-shaped cluster: centroid at ``centre``, box of ``size``, uniform colour."""
    c = np.asarray(centre, dtype=np.float64)
    half = np.asarray(size, dtype=np.float64) / 2
    hsl = colorsys.rgb_to_hls(*rgb)
    voxels = max(1, int(np.prod(np.asarray(size) / EDGE) * density))
    return Cluster(
        id=cid,
        voxels=np.zeros((0, 3), dtype=np.int32),
        voxel_count=voxels,
        color_mean_rgb=np.asarray(rgb, dtype=np.float32),
        color_var_rgb=np.zeros(3, dtype=np.float32),
        color_mean_hsl=np.asarray((hsl[0], hsl[2], hsl[1]), dtype=np.float32),
        color_var_hsl=np.zeros(3, dtype=np.float32),
        bbox_min=c - half,
        bbox_max=c + half,
        centroid=c,
        density=density,
        volume=voxels * EDGE**3,
    )


def frame(frame_id: int, clusters: list[Cluster], epoch: int = 0, pose: np.ndarray | None = None) -> Clusters:
    return Clusters(
        frame_id=frame_id,
        stamp_ns=frame_id * PERIOD_NS,
        clusters=clusters,
        voxel_edge=EDGE,
        world_epoch=epoch,
        ego_pose=np.eye(4) if pose is None else pose,
    )


def ego(frame_id: int, pose: np.ndarray | None = None, valid: bool = True, epoch: int = 0) -> EgoMotion:
    return EgoMotion(
        frame_id=frame_id,
        stamp_ns=frame_id * PERIOD_NS,
        pose=np.eye(4) if pose is None else pose,
        valid=valid,
        world_epoch=epoch,
    )


def step(tracker: Tracker, frame_id: int, clusters: list[Cluster], **kw: object) -> Obstacles:
    pose = kw.pop("pose", None)
    epoch = kw.pop("epoch", 0)
    valid = kw.pop("valid", True)
    return tracker.process(frame(frame_id, clusters, epoch, pose), ego(frame_id, pose, valid, epoch))  # type: ignore[arg-type]


def new_tracker(**overrides: object) -> Tracker:
    cfg = Config()
    for key, value in overrides.items():
        setattr(cfg.tracker, key, value)
    return Tracker.from_config(cfg)


# ------------------------------------------------------------------ association


def test_greedy_takes_smallest_pair_first_not_the_row_minimum() -> None:
    # track 0's best cluster is 0 (1.0), but (track 1, cluster 0) is smaller still (0.5): greedy
    # gives cluster 0 to track 1 and track 0 falls back to cluster 1.
    d = np.array([[1.0, 2.0], [0.5, 2.5]])
    rows, cols = greedy_pairs(d, gate=3.0)
    assert dict(zip(rows.tolist(), cols.tolist(), strict=True)) == {1: 0, 0: 1}


def test_greedy_leaves_pairs_over_the_threshold_unassociated() -> None:
    d = np.array([[1.0, 9.0], [9.0, 3.5], [0.2, 8.0]])
    rows, cols = greedy_pairs(d, gate=3.0)
    assert rows.tolist() == [2] and cols.tolist() == [0]
    rows, cols = greedy_pairs(np.zeros((0, 4)), gate=3.0)
    assert rows.size == 0 and cols.size == 0


def test_distance_terms_are_weighted_as_configured() -> None:
    w = Weights(position=1.0, color=0.0, size=0.0, density=0.0, gate=3.0, position_gate=10.0)
    grey, unit = np.zeros((1, 3)), np.ones((1, 3))
    args_t = (np.array([[0.0, 0, 0]]), grey, grey, unit, np.array([0.5]))
    args_c = (np.array([[3.0, 4, 0], [0, 0, 1]]), np.zeros((2, 3)), np.zeros((2, 3)), np.ones((2, 3)), np.full(2, 0.5))
    # position counts in standard deviations of the pair's offset
    assert np.allclose(distance_matrix(w, np.full((1, 2), 0.25), *args_t, *args_c), [[10.0, 2.0]])
    # beyond the position gate a pair is never associated, however alike
    w = Weights(position=0.0, color=0.0, size=0.0, density=0.0, gate=3.0, position_gate=3.0)
    d = distance_matrix(w, np.full((1, 2), 1.0), *args_t, *args_c)
    assert np.isinf(d[0, 0]) and d[0, 1] == 0.0
    # hue is circular (0.95 and 0.05 are 0.1 apart) and counts only as far as both are saturated
    w = Weights(position=0.0, color=1.0, size=0.0, density=0.0, gate=3.0, position_gate=3.0)
    hsl_t = np.array([[0.95, 1.0, 0.5], [0.95, 0.0, 0.5]])
    hsl_c = np.array([[0.05, 1.0, 0.5], [0.45, 0.0, 0.5]])
    d = distance_matrix(w, np.ones((2, 2)), *(np.repeat(a, 2, axis=0) for a in args_t[:2]), hsl_t,
                        *(np.repeat(a, 2, axis=0) for a in args_t[3:]),
                        *(np.repeat(a, 2, axis=0) for a in args_t[:2]), hsl_c,
                        *(np.repeat(a, 2, axis=0) for a in args_t[3:]))  # fmt: skip
    assert np.isclose(d[0, 0], 0.1) and np.isclose(d[1, 1], 0.0)  # two greys: their hues are noise


def test_position_variance_grows_with_track_uncertainty_and_range() -> None:
    r = np.stack([np.eye(3) * 0.01, np.eye(3) * 0.25])
    p = np.stack([np.eye(3) * 0.04, np.eye(3) * 1.0])
    var = position_variance(p, np.ones(2), np.ones((2, 3)), r, np.ones((2, 3)))
    assert np.allclose(var, [[0.05, 0.29], [1.01, 1.25]])


def test_two_crossing_colours_keep_their_identities() -> None:
    tracker = new_tracker()
    red, blue = (0.8, 0.1, 0.1), (0.1, 0.1, 0.8)
    ids: dict[str, set[int]] = {"red": set(), "blue": set()}
    for k in range(30):
        x_red, x_blue = 10.0 + 0.1 * k, 13.0 - 0.1 * k  # they pass each other at k = 15
        out = step(tracker, k, [cluster(0, (x_red, 2.0, 0.75), rgb=red), cluster(1, (x_blue, 2.3, 0.75), rgb=blue)])
        for o in out.obstacles:
            ids["red" if o.color_rgb[0] > 0.5 else "blue"].add(o.id)
    assert len(ids["red"]) == 1 and len(ids["blue"]) == 1


# ------------------------------------------------------------------ queues


def test_acceptance_promoted_after_n_frames_then_ghost_then_dropped() -> None:
    tracker = new_tracker(accept_frames=3, ghost_frames=4)
    obj = [cluster(0, (10.0, 0.0, 0.75))]
    states = [[o.state for o in step(tracker, k, obj).obstacles] for k in range(3)]
    assert states == [["acceptance"], ["acceptance"], ["tracked"]]
    ghost_states = [[o.state for o in step(tracker, k, []).obstacles] for k in range(3, 9)]
    assert ghost_states == [["ghost"]] * 4 + [[], []]


def test_acceptance_track_missing_one_frame_is_discarded() -> None:
    tracker = new_tracker(accept_frames=3)
    step(tracker, 0, [cluster(0, (10.0, 0.0, 0.75))])
    step(tracker, 1, [cluster(0, (10.0, 0.0, 0.75))])
    assert step(tracker, 2, []).obstacles == []


def test_acceptance_allowance_keeps_a_new_track_through_one_missed_frame() -> None:
    # a pedestrian the segmentation finds every other frame: frames seen count, the misses are forgiven
    tracker = new_tracker(accept_frames=3, accept_misses=1)
    first = step(tracker, 0, [cluster(0, (10.0, 0.0, 0.75))]).obstacles[0].id
    assert step(tracker, 1, []).obstacles[0].state == "acceptance"
    step(tracker, 2, [cluster(0, (10.0, 0.0, 0.75))])
    step(tracker, 3, [])
    (o,) = step(tracker, 4, [cluster(0, (10.0, 0.0, 0.75))]).obstacles
    assert o.id == first and o.state == "tracked"
    step(tracker, 5, [])
    step(tracker, 6, [])
    assert step(tracker, 7, []).obstacles[0].state == "ghost"


def test_ghost_revived_keeps_its_id() -> None:
    tracker = new_tracker(accept_frames=2, ghost_frames=5)
    obj = [cluster(0, (10.0, 0.0, 0.75))]
    first = [step(tracker, k, obj) for k in range(3)][-1].obstacles[0]
    assert step(tracker, 3, []).obstacles[0].state == "ghost"
    assert step(tracker, 4, []).obstacles[0].state == "ghost"
    back = step(tracker, 5, obj).obstacles
    assert [(o.id, o.state) for o in back] == [(first.id, "tracked")]


def walkers_then_merged(tracker: Tracker, merged_frames: int, speed: float = 0.0) -> list[str]:
    """Two walkers side by side walking at ``speed`` along x, each seen alone for 10 frames, then one cluster for both.

    Returns the second walker's state on each merged frame ("" once it is gone).
    """
    red, blue = (0.7, 0.2, 0.2), (0.2, 0.2, 0.7)
    walker = (0.5, 0.5, 1.8)
    for k in range(10):
        x = 15.0 + speed * 0.1 * k
        out = step(tracker, k, [cluster(0, (x, -1.0, 0.9), walker, red), cluster(1, (x, 0.0, 0.9), walker, blue)])
    (second,) = [o.id for o in out.obstacles if abs(o.centroid[1]) < 0.1]
    states = []
    for k in range(10, 10 + merged_frames):
        both = cluster(0, (15.0 + speed * 0.1 * k, -0.6, 0.9), (0.5, 1.5, 1.8), red)  # smear joins them
        states.append(next((o.state for o in step(tracker, k, [both]).obstacles if o.id == second), ""))
    return states


def test_a_walker_merged_into_his_neighbours_cluster_stays_tracked_for_a_few_frames() -> None:
    # the first walker's track takes the joined cluster; the second stays reported where he stands
    coasting = new_tracker(coast_merged_frames=3, coast_min_age=8)
    assert walkers_then_merged(coasting, 5) == ["tracked"] * 3 + ["ghost"] * 2
    assert walkers_then_merged(new_tracker(coast_merged_frames=0, coast_standing_frames=0), 2) == ["ghost"] * 2
    # a track younger than coast_min_age turns ghost at once: its velocity is still a guess
    assert walkers_then_merged(new_tracker(coast_merged_frames=3, coast_min_age=20), 1) == ["ghost"]
    # one faster than coast_max_speed_mps too (a car's rear is upright as well)
    assert walkers_then_merged(new_tracker(coast_max_speed_mps=5.0), 1, speed=1.5) == ["tracked"]
    assert walkers_then_merged(new_tracker(coast_max_speed_mps=1.0), 1, speed=1.5) == ["ghost"]


def lost_for_frames(tracker: Tracker, speed: float, lost: int) -> list[tuple[str, bool, float]]:
    """A walker crossing the road at ``speed`` (along y, 15 m ahead), seen 14 frames, then no cluster
    anywhere for ``lost`` frames, then seen again once. His track's (state, moving, distance from
    where he truly is) on each frame after the 14th ("" and NaN once it is gone)."""
    walker = (0.5, 0.5, 1.8)

    def where(k: int) -> tuple[float, float, float]:
        return (15.0, -3.0 + speed * 0.1 * k, 0.9)

    out = [step(tracker, k, [cluster(0, where(k), walker)]) for k in range(14)][-1]
    (track,) = [o.id for o in out.obstacles]
    states = []
    for k in range(14, 14 + lost + 1):
        seen = [cluster(0, where(k), walker)] if k == 14 + lost else []
        o = next((o for o in step(tracker, k, seen).obstacles if o.id == track), None)
        off = np.nan if o is None else float(np.hypot(*(np.asarray(o.centroid[:2]) - where(k)[:2])))
        states.append(("", False, off) if o is None else (o.state, o.moving, off))
    return states


def test_a_moving_walker_no_cluster_finds_for_two_frames_stays_tracked_where_he_walks() -> None:
    # the segmentation loses a far walker for a frame or two (crossing's walker at 17-24 m);
    # his track, labelled moving, is reported where its filter carries it rather than turned ghost
    coasting = lost_for_frames(new_tracker(coast_moving_frames=2), 1.5, 3)
    assert [(s, m) for s, m, _ in coasting] == [("tracked", True)] * 2 + [("ghost", True), ("tracked", True)]
    assert max(off for _, _, off in coasting) < 0.3
    assert [s for s, _, _ in lost_for_frames(new_tracker(coast_moving_frames=0), 1.5, 1)] == ["ghost", "tracked"]
    # a standing object's track coasts by its own count, none here: a ghost at once
    standing = lost_for_frames(new_tracker(coast_moving_frames=2, coast_standing_frames=0), 0.0, 2)
    assert [(s, m) for s, m, _ in standing] == [("ghost", False)] * 2 + [("tracked", False)]


def test_a_standing_object_no_cluster_finds_for_a_frame_stays_tracked_where_it_stands() -> None:
    # a far pole's cluster goes missing for a frame; its track stays reported, standing, where it stood
    coasting = lost_for_frames(new_tracker(coast_standing_frames=1), 0.0, 2)
    assert [(s, m) for s, m, _ in coasting] == [("tracked", False), ("ghost", False), ("tracked", False)]
    assert max(off for _, _, off in coasting) < 0.1
    assert [s for s, _, _ in lost_for_frames(new_tracker(coast_standing_frames=2), 0.0, 3)] == (
        ["tracked"] * 2 + ["ghost", "tracked"]
    )
    # a track younger than coast_min_age turns ghost at once: it may be a phantom's
    young = lost_for_frames(new_tracker(coast_standing_frames=1, coast_min_age=20), 0.0, 1)
    assert [s for s, _, _ in young] == ["ghost", "tracked"]


def test_unmatched_cluster_starts_a_new_acceptance_track() -> None:
    tracker = new_tracker()
    for k in range(5):
        step(tracker, k, [cluster(0, (10.0, 0.0, 0.75))])
    out = step(tracker, 5, [cluster(0, (10.0, 0.0, 0.75)), cluster(1, (20.0, 5.0, 0.75), rgb=(0.1, 0.7, 0.1))])
    assert sorted(o.state for o in out.obstacles) == ["acceptance", "tracked"]


# ------------------------------------------------------------------ Kalman filter and motion


def test_batched_filter_matches_filterpy() -> None:
    rng = np.random.default_rng(3)
    n, dt, accel, meas = 7, 0.1, np.array([1.0, 1.0, 0.1]), 0.15
    p0 = kalman.initial_covariance(np.eye(3)[None] * meas**2, np.array([5.0, 5.0, 0.3]) ** 2)[0]
    starts = rng.normal(size=(n, 3)) * 10
    x = np.hstack([starts, np.zeros((n, 3))])
    p = np.broadcast_to(p0, (n, 6, 6)).copy()
    filters = []
    for i in range(n):
        kf = KalmanFilter(dim_x=6, dim_z=3)
        kf.x = x[i].reshape(6, 1).copy()
        kf.P = p0.copy()
        kf.F = kalman.transition(dt)
        q = np.zeros((6, 6))
        for axis in range(3):
            block = Q_discrete_white_noise(dim=2, dt=dt, var=accel[axis] ** 2)
            q[np.ix_([axis, axis + 3], [axis, axis + 3])] = block
        kf.Q = q
        kf.H = kalman.H
        kf.R = np.eye(3) * meas**2
        filters.append(kf)
    assert np.allclose(filters[0].Q, kalman.process_noise(dt, accel))
    f, q = kalman.transition(dt), kalman.process_noise(dt, accel)
    for k in range(20):
        z = starts + np.array([1.0, -0.5, 0.0]) * k * dt + rng.normal(scale=meas, size=(n, 3))
        x, p = kalman.predict(x, p, f, q)
        x, p = kalman.update(x, p, z, np.eye(3) * meas**2)
        for i, kf in enumerate(filters):
            kf.predict()
            kf.update(z[i])
    assert np.allclose(x, np.stack([kf.x.ravel() for kf in filters]), atol=1e-10)
    assert np.allclose(p, np.stack([kf.P for kf in filters]), atol=1e-12)


def test_velocity_correction_matches_filterpy_and_leaves_out_what_it_gates() -> None:
    rng = np.random.default_rng(4)
    n = 5
    a = rng.normal(size=(n, 6, 6))
    p = a @ np.swapaxes(a, 1, 2) + np.eye(6)[None]  # symmetric positive definite
    x = rng.normal(size=(n, 6))
    v = x[:, 3:5] + rng.normal(scale=0.5, size=(n, 2))
    v[3] = x[3, 3:5] + 100.0  # far outside what the filter expects
    std = np.array([0.2, 0.3, 0.5, 0.2, 1.0])
    x_new, p_new = x.copy(), p.copy()
    done = kalman.correct_velocity(x_new, p_new, np.arange(n), v, std, gate=9.0)
    assert done.tolist() == [True, True, True, False, True]
    for i in range(n):
        kf = KalmanFilter(dim_x=6, dim_z=2)
        kf.x, kf.P = x[i].reshape(6, 1).copy(), p[i].copy()
        kf.H = np.zeros((2, 6))
        kf.H[0, 3] = kf.H[1, 4] = 1.0
        kf.R = np.eye(2) * std[i] ** 2
        if done[i]:
            kf.update(v[i])
        np.testing.assert_allclose(x_new[i], kf.x.ravel(), atol=1e-10)
        np.testing.assert_allclose(p_new[i], kf.P, atol=1e-10)


def test_constant_velocity_target_speed_converges() -> None:
    rng = np.random.default_rng(1)
    tracker = new_tracker()
    velocity = np.array([6.0, -2.0, 0.0])  # 6.3 m/s
    for k in range(40):
        centre = np.array([5.0, 4.0, 0.75]) + velocity * k * 0.1 + rng.normal(scale=[0.1, 0.1, 0.03])
        out = step(tracker, k, [cluster(0, centre, size=(4.0, 1.8, 1.5))])
    (o,) = out.obstacles
    assert abs(o.speed - np.linalg.norm(velocity)) < 0.1
    assert np.allclose(o.velocity, velocity, atol=0.15)
    assert o.moving and o.state == "tracked"


def speeds_after_a_jump(jump_speed_std: float) -> list[float]:
    """A car at 8 m/s whose cluster steps back 2 m and goes on at 1.5 m/s (the track slid onto
    something slower); the gates are open so that every cluster is associated."""
    rng = np.random.default_rng(3)
    tracker = new_tracker(jump_speed_std=jump_speed_std, position_gate=1e9, gate=1e9)
    position, speeds = np.array([6.0, 3.0, 0.75]), []
    for k in range(30):
        if k == 15:
            position = position - np.array([2.0, 0.0, 0.0])
        position = position + np.array([8.0 if k < 15 else 1.5, 0.0, 0.0]) * 0.1
        out = step(tracker, k, [cluster(0, position + rng.normal(scale=[0.05, 0.05, 0.02]), size=(4.0, 1.8, 1.5))])
        (o,) = out.obstacles
        assert o.id == 1
        speeds.append(o.speed)
    return speeds


def test_a_re_anchored_track_learns_its_new_speed_again() -> None:
    # the jump re-anchors the position; with its kept velocity doubted, the next clusters set it
    # again, where without the doubt it stays near 8 m/s, re-anchored frame after frame
    doubted, kept = speeds_after_a_jump(3.0), speeds_after_a_jump(0.0)
    assert doubted[14] == pytest.approx(8.0, abs=0.3) and kept[14] == pytest.approx(8.0, abs=0.3)
    assert abs(doubted[22] - 1.5) < 0.5
    assert kept[22] > 6.0


def ids_after_a_step(step_frame: int, young_jump_frames: int) -> list[list[int]]:
    """A standing box whose cluster is 3 m further off from ``step_frame`` on (gates open)."""
    tracker = new_tracker(young_jump_frames=young_jump_frames, position_gate=1e9, gate=1e9)
    ids = []
    for k in range(step_frame + 3):
        centre = (8.0, 3.0, 0.75) if k < step_frame else (11.0, 3.0, 0.75)
        out = step(tracker, k, [cluster(0, centre, size=(1.0, 1.0, 1.5))])
        ids.append(sorted(o.id for o in out.obstacles if o.state != "ghost"))
    return ids


def test_a_young_track_is_not_carried_onto_a_cluster_it_would_re_anchor_on() -> None:
    # three frames old, the track is left behind and the far cluster starts its own track ...
    assert ids_after_a_step(3, young_jump_frames=4)[3:] == [[2], [2], [2]]
    assert ids_after_a_step(3, young_jump_frames=0)[3:] == [[1], [1], [1]]
    # ... four frames old, it re-anchors on it and keeps its identity
    assert ids_after_a_step(4, young_jump_frames=4)[4:] == [[1], [1], [1]]


def after_a_lurch(retake_m: float) -> tuple[list[list[tuple[int, str, float]]], int]:
    """A cyclist at 6 m/s whose cluster lies 1.2 m further ahead from frame 15 on (more of him in
    view): further from its settled track's prediction than association pairs. The obstacles of
    each frame, and how many clusters were taken back."""
    tracker, rng = new_tracker(jump_retake_m=retake_m), np.random.default_rng(1)
    position, seen = np.array([8.0, -3.0, 0.8]), []
    for k in range(20):
        position = position + np.array([0.6, 0.0, 0.0])
        shown = position + np.array([1.2 if k >= 15 else 0.0, 0.0, 0.0]) + rng.normal(scale=[0.03, 0.03, 0.01])
        out = step(tracker, k, [cluster(0, shown, size=(1.8, 0.6, 1.6))])
        seen.append([(o.id, o.state, o.speed) for o in out.obstacles])
    return seen, tracker.counters["retaken"]


def test_a_moving_track_takes_its_cluster_back_when_it_lurches_ahead() -> None:
    (kept, retaken), (born, _) = after_a_lurch(1.5), after_a_lurch(0.0)
    assert retaken == 1  # once: from then on its prediction follows the cluster
    assert [(i, state) for i, state, _ in kept[14]] == [(1, "tracked")]
    for frame in kept[15:]:  # re-anchored on it, its speed kept
        ((i, state, speed),) = frame
        assert (i, state) == (1, "tracked") and speed == pytest.approx(6.0, abs=0.5)
    # without it the cluster starts a track of its own at rest, the cyclist's goes on as a ghost
    assert [(i, state) for i, state, _ in born[15]] == [(1, "ghost"), (2, "acceptance")]
    assert born[16][1][2] < 4.0


def test_moving_label_needs_a_trustworthy_speed_and_comes_within_five_frames() -> None:
    rng = np.random.default_rng(2)
    tracker = new_tracker()
    labels = []
    for k in range(12):
        centre = np.array([8.0, 2.0, 0.9]) + np.array([0.0, 1.5, 0.0]) * k * 0.1 + rng.normal(scale=0.05, size=3)
        out = step(tracker, k, [cluster(0, centre, size=(0.6, 0.6, 1.8))])  # a walking pedestrian
        labels.append(out.obstacles[0].moving)
    assert not labels[0] and not labels[1]  # two frames cannot tell 1.5 m/s from noise
    assert any(labels[:8])


def labels_of_a_walk(floor_m: list[float], **overrides: object) -> list[bool]:
    """A 1.5 m/s walker's labels, frame by frame, its cluster's floor given per frame."""
    rng = np.random.default_rng(2)
    tracker = new_tracker(**overrides)
    labels = []
    for k, floor in enumerate(floor_m):
        centre = np.array([8.0, 2.0, 0.9]) + np.array([0.0, 1.5, 0.0]) * k * 0.1 + rng.normal(scale=0.05, size=3)
        piece = dataclasses.replace(cluster(0, centre, size=(0.6, 0.6, 1.8)), floor_m=floor)
        labels.append(step(tracker, k, [piece]).obstacles[0].moving)
    return labels


def test_what_is_held_up_off_the_road_never_turns_moving_but_a_mover_keeps_its_label() -> None:
    grounded = labels_of_a_walk([0.3] * 12, moving_max_floor_m=1.0)
    assert any(grounded[:8])
    assert labels_of_a_walk([1.4] * 12, moving_max_floor_m=0.0) == grounded  # the rule off: the floor is not read
    assert not any(labels_of_a_walk([1.4] * 12, moving_max_floor_m=1.0))  # a crown's piece sliding along
    first = grounded.index(True)
    # once moving, legs hidden behind a parked car's bonnet take nothing away
    assert labels_of_a_walk([0.3] * (first + 1) + [1.4] * (11 - first), moving_max_floor_m=1.0) == grounded


def test_static_object_seen_from_moving_vehicle_never_moving() -> None:
    rng = np.random.default_rng(4)
    tracker = new_tracker()
    parked = np.array([20.0, -3.0, 0.75])
    for k in range(60):
        pose = make_pose(rot_z(0.002 * k), [1.0 * k, 0.0, 0.0])  # 10 m/s, slowly turning
        centre = parked + rng.normal(scale=[0.1, 0.1, 0.05])
        out = step(tracker, k, [cluster(0, centre, size=(4.0, 1.8, 1.5))], pose=pose)
        assert not any(o.moving for o in out.obstacles), k
    (o,) = out.obstacles
    assert o.speed < 0.5
    # seen from the vehicle the parked car comes towards it at the vehicle's speed
    assert np.allclose(o.velocity_rel[:2], (pose[:3, :3].T @ np.array([-10.0, 0.0, 0.0]))[:2], atol=0.6)


def test_parked_car_whose_visible_part_grows_stays_stationary() -> None:
    # driving past: first only the rear is seen, then the side comes into view voxel by voxel and
    # the centroid slides forward 2 m in 1.6 s (1.25 m/s), while the car stands still.
    rng = np.random.default_rng(5)
    tracker = new_tracker()
    rear = 20.0
    for k in range(40):
        visible = min(4.5, 0.5 + EDGE * k)
        centre = np.array([rear + visible / 2, -3.0, 0.75]) + rng.normal(scale=0.03, size=3)
        pose = make_pose(np.eye(3), [1.0 * k, 0.0, 0.0])
        out = step(tracker, k, [cluster(0, centre, size=(visible, 1.8, 1.5))], pose=pose)
        assert not any(o.moving for o in out.obstacles), k


def block_cut_by_the_image(margin: float) -> list[Obstacles]:
    """A building block left of the road (world x 20-32, y 4-6.5, 3 m tall) passed at 10 m/s.

    The image's left edge (dy / dx = 0.5 from the camera) cuts the block's near end from the
    third frame on; that end then slides forward with the vehicle while the far end stands still.
    """
    tracker = new_tracker(view_margin_m=margin)
    block = box_voxels((20.0, 4.0, 0.0), (32.0, 6.5, 3.0))
    centres = (block + 0.5) * EDGE
    out = []
    for k in range(12):
        pose = make_pose(np.eye(3), [6.0 + 1.0 * k, 0.0, 0.0])
        seen = counted(block[centres[:, 1] <= 0.5 * (centres[:, 0] - pose[0, 3])])
        clusters = Clusters(
            frame_id=k, stamp_ns=k * PERIOD_NS, clusters=[seen], voxel_edge=EDGE, ego_pose=pose,
            view=np.array([0.0, 0.0, 0.5, -0.5]),
        )  # fmt: skip
        out.append(tracker.process(clusters, ego(k, pose)))
    return out


def test_a_block_cut_by_the_images_side_edge_is_followed_at_its_far_end() -> None:
    followed = block_cut_by_the_image(margin=0.5)
    assert all(not o.moving for frame in followed for o in frame.obstacles)
    (block,) = followed[-1].obstacles
    assert block.speed < 0.5
    # followed at the near end, the track takes the edge's slide for the block's speed
    (slid,) = block_cut_by_the_image(margin=0.0)[-1].obstacles
    assert slid.speed > 2.5


# ------------------------------------------------------------------ bad input


def test_new_world_epoch_clears_tracks() -> None:
    tracker = new_tracker()
    for k in range(4):
        step(tracker, k, [cluster(0, (10.0, 0.0, 0.75))])
    old = {o.id for o in step(tracker, 4, [cluster(0, (10.0, 0.0, 0.75))]).obstacles}
    out = step(tracker, 5, [cluster(0, (10.0, 0.0, 0.75))], epoch=1)
    assert [o.state for o in out.obstacles] == ["acceptance"] and out.obstacles[0].id not in old
    assert out.world_epoch == 1 and tracker.counters["epoch_resets"] == 1


def test_nan_centroids_dropped_and_counted() -> None:
    tracker = new_tracker()
    bad = cluster(1, (12.0, 0.0, 0.75))
    bad.centroid = np.array([np.nan, 0.0, 0.75])
    out = step(tracker, 0, [cluster(0, (10.0, 0.0, 0.75)), bad])
    assert len(out.obstacles) == 1 and tracker.counters["nan_clusters"] == 1
    out = step(tracker, 1, [bad])
    assert out.obstacles == [] and tracker.counters["nan_clusters"] == 2 and tracker.counters["empty_frames"] == 1
    assert all(np.isfinite(tracker.tracks.x).all() for _ in [0])


def test_stale_frames_ignored_and_counted() -> None:
    tracker = new_tracker()
    for k in range(4):
        step(tracker, k, [cluster(0, (10.0 + 0.5 * k, 0.0, 0.75))])
    before = tracker.tracks.x.copy()
    out = step(tracker, 2, [cluster(0, (50.0, 9.0, 0.75))])
    assert tracker.counters["stale_frames"] == 1 and out.frame_id == 2
    assert np.array_equal(tracker.tracks.x, before) and len(out.obstacles) == 1
    step(tracker, 3, [])
    assert tracker.counters["stale_frames"] == 2


def test_gap_is_predicted_through_with_the_stamp_difference() -> None:
    tracker = new_tracker(ghost_frames=5)
    velocity = np.array([5.0, 0.0, 0.0])
    for k in range(15):
        step(tracker, k, [cluster(0, np.array([5.0, 1.0, 0.75]) + velocity * k * 0.1)])
    ident = step(tracker, 15, [cluster(0, np.array([5.0, 1.0, 0.75]) + velocity * 1.5)]).obstacles[0].id
    # frames 16..18 never arrive; at frame 19 the car is 2 m further: one association, no new track
    out = step(tracker, 19, [cluster(0, np.array([5.0, 1.0, 0.75]) + velocity * 1.9)])
    assert [(o.id, o.state) for o in out.obstacles] == [(ident, "tracked")]
    assert tracker.counters["gaps"] == 1 and tracker.counters["gap_frames"] == 3
    assert abs(out.obstacles[0].speed - 5.0) < 0.3
    # a gap longer than the ghost life retires the unseen track
    out = step(tracker, 40, [])
    assert out.obstacles == []


def test_invalid_egomotion_predicts_without_correcting() -> None:
    tracker = new_tracker()
    for k in range(10):
        step(tracker, k, [cluster(0, (10.0, 0.0, 0.75))])
    # an invalid pose puts the cluster 0.5 m off (5 m/s if believed): kept associated, not believed
    out = step(tracker, 10, [cluster(0, (10.5, 0.0, 0.75))], valid=False)
    (o,) = out.obstacles
    assert o.state == "tracked" and not o.moving and o.speed < 0.3
    assert tracker.counters["ego_invalid"] == 1


def test_output_survives_the_codec_and_copies_ids() -> None:
    tracker = new_tracker()
    pose = make_pose(rot_z(0.3), [4.0, 1.0, 0.0])
    out = tracker.process(frame(7, [cluster(0, (10.0, 0.0, 0.75))], pose=pose), ego(7, pose))
    back = decode(encode(out), Obstacles)
    assert back.frame_id == 7 and back.stamp_ns == 7 * PERIOD_NS and np.allclose(back.ego_pose, pose)
    (o,) = back.obstacles
    assert o.state == "acceptance" and np.allclose(o.centroid, (10.0, 0.0, 0.75))
    assert np.allclose(o.bbox_min, (9.5, -0.5, 0.0)) and np.allclose(o.bbox_max, (10.5, 0.5, 1.5))


@pytest.mark.timeout(60)
def test_fifty_obstacles_tracked_without_identity_swaps() -> None:
    rng = np.random.default_rng(6)
    tracker = new_tracker()
    centres = np.column_stack([rng.uniform(2, 28, 50), rng.uniform(-8, 8, 50), np.full(50, 0.75)])
    velocities = np.column_stack([rng.uniform(-3, 3, 50), rng.uniform(-1, 1, 50), np.zeros(50)])
    colours = rng.uniform(0.1, 0.9, (50, 3))
    ids_of: dict[int, set[int]] = {i: set() for i in range(50)}
    for k in range(20):
        pts = centres + velocities * k * 0.1 + rng.normal(scale=0.05, size=(50, 3))
        out = step(tracker, k, [cluster(i, pts[i], size=(0.8, 0.8, 1.5), rgb=tuple(colours[i])) for i in range(50)])
        for o in out.obstacles:
            nearest = int(np.argmin(np.linalg.norm(pts - o.centroid, axis=1)))
            ids_of[nearest].add(o.id)
    assert len(out.obstacles) == 50 and all(o.state == "tracked" for o in out.obstacles)
    assert all(len(v) == 1 for v in ids_of.values())


# ------------------------------------------------------------------ anchors, pieces, jumps


def box_voxels(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> np.ndarray:
    """The integer coordinates of the voxels filling the box ``lo``..``hi``."""
    axes = [np.arange(np.floor(a / EDGE), np.ceil(b / EDGE)) for a, b in zip(lo, hi, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.int32)


def surface(
    lo: tuple[float, float, float],
    hi: tuple[float, float, float],
    cid: int = 0,
    rgb: tuple[float, float, float] = (0.6, 0.2, 0.2),
) -> Cluster:
    """A cluster made of the voxels filling the box ``lo``..``hi``: centroid and box from its voxels."""
    return of_voxels(box_voxels(lo, hi), cid, rgb)


def of_voxels(voxels: np.ndarray, cid: int = 0, rgb: tuple[float, float, float] = (0.6, 0.2, 0.2)) -> Cluster:
    """A cluster made of these voxels: centroid and box from them."""
    centres = (voxels + 0.5) * EDGE
    base = cluster(cid, centres.mean(axis=0), rgb=rgb)
    return Cluster(
        id=cid, voxels=voxels, voxel_count=len(voxels), color_mean_rgb=base.color_mean_rgb,
        color_var_rgb=base.color_var_rgb, color_mean_hsl=base.color_mean_hsl, color_var_hsl=base.color_var_hsl,
        bbox_min=centres.min(axis=0) - EDGE / 2, bbox_max=centres.max(axis=0) + EDGE / 2,
        centroid=centres.mean(axis=0), density=1.0, volume=len(voxels) * EDGE**3,
    )  # fmt: skip


def test_anchor_stays_on_the_faces_in_view_while_the_far_side_grows() -> None:
    # a parked car right of the road: its rear (near x) and its road side (high y) face the camera
    short, long = surface((20.0, -4.0, 0.25), (21.0, -2.25, 1.5)), surface((20.0, -4.0, 0.25), (24.5, -2.25, 1.5))
    points, side, _, _, _, _ = anchors([short, long], np.array([short.centroid, long.centroid]), np.eye(4), EDGE)
    assert side.tolist() == [2, 2]
    a, b = points[0, 2], points[1, 2]
    assert abs(a[0] - b[0]) < 0.3 and abs(a[1] - b[1]) < 0.01  # the centroids are 1.75 m apart
    assert abs(short.centroid[0] - long.centroid[0]) > 1.5


def test_the_anchors_sort_and_selection_agree_with_numpys() -> None:
    # the counting sort and the buffered selection stand in for np.sort; ties, runs of one value and
    # selections far from both ends (which sort instead) included
    rng = np.random.default_rng(8)
    buffer = np.empty(SELECT_MAX + 1)
    for trial in range(300):
        m = int(rng.integers(1, 400))
        values = rng.normal(size=m) if trial % 3 else np.round(rng.normal(size=m) * 3.0) / 3.0
        if trial % 50 == 0:
            values[:] = 1.5
        order = _order(values)
        assert sorted(order.tolist()) == list(range(m))
        np.testing.assert_array_equal(values[order], np.sort(values))
        for k in {0, m - 1, m // 2, min(4, m - 1), int(rng.integers(0, m))}:
            assert _kth(values, k, buffer) == np.sort(values)[k]


def test_the_faces_are_the_percentiles_of_each_clusters_own_voxels() -> None:
    # the compiled pass against the definition, cluster by cluster, under a turned and moved
    # vehicle: the near and far faces (5 / 95 % of the voxels in vehicle x), the side faces (in
    # y), and for a narrow cluster, narrow by the 5-95 % of its points across the line of sight,
    # the interquartile mean range of its points; a cluster without counts weighs its voxels alike;
    # and how wide its points are across the line of sight and, if narrow, how deep along it
    rng = np.random.default_rng(3)
    yaw = 0.4
    pose = np.eye(4)
    pose[0:2, 0:2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    pose[0:3, 3] = [5.0, -2.0, 0.3]
    clusters = []
    for k in range(16):
        spread = rng.integers(1, 4 if k % 2 else 30, 3)  # thin and wide ones
        voxels = rng.integers(-spread, spread, (int(rng.integers(1, 150)), 3)) + rng.integers(-60, 60, 3)
        c = of_voxels(np.unique(voxels, axis=0).astype(np.int32), cid=k)
        if k % 4 != 3:
            c = dataclasses.replace(c, voxel_points=rng.integers(0, 30, c.voxel_count).astype(np.int32))
        clusters.append(c)
    points, side, far, narrow, _, spread = anchors(clusters, np.array([c.centroid for c in clusters]), pose, EDGE)

    def by_count(values: np.ndarray, share: float) -> float:
        return float(np.sort(values)[max(int(np.ceil(share * len(values))) - 1, 0)])

    def by_points(values: np.ndarray, w: np.ndarray, share: float) -> float:
        order = np.argsort(values, kind="stable")
        cum = np.cumsum(w[order])
        return float(values[order][min(int(np.searchsorted(cum, share * cum[-1])), len(values) - 1)])

    def interquartile_mean(values: np.ndarray, w: np.ndarray) -> float:
        # each value's weight clipped to the part of the running total between its quartiles
        order = np.argsort(values, kind="stable")
        upper = np.cumsum(w[order])
        lower = upper - w[order]
        inside = np.clip(upper, 0.25 * upper[-1], 0.75 * upper[-1]) - np.clip(lower, 0.25 * upper[-1], 0.75 * upper[-1])
        return float((inside * values[order]).sum() / inside.sum())

    rotation, origin = pose[0:3, 0:3], pose[0:3, 3]
    assert 3 <= narrow.sum() <= len(clusters) - 3, narrow  # both kinds are tested
    for k, c in enumerate(clusters):
        local = ((c.voxels + 0.5) * EDGE - origin) @ rotation
        w = c.voxel_points + 1e-3 if len(c.voxel_points) else np.ones(c.voxel_count)
        ray = ((c.centroid - origin) @ rotation)[0:2]
        ray /= np.linalg.norm(ray)
        across = ray[0] * local[:, 1] - ray[1] * local[:, 0]
        near_x, far_x = by_count(local[:, 0], 0.05), by_count(local[:, 0], 0.95)
        y_lo, y_hi = by_count(local[:, 1], 0.05), by_count(local[:, 1], 0.95)
        width = by_points(across, w, 0.95) - by_points(across, w, 0.05)
        thin = width < anchor_module.NARROW_M
        assert spread[k, 0] == pytest.approx(width, abs=1e-9)
        if thin:  # the middle half's depth along the line of sight, binned an eighth of a voxel apart
            along = ray[0] * local[:, 0] + ray[1] * local[:, 1]
            depth = by_points(along, w, 0.75) - by_points(along, w, 0.25)
            assert spread[k, 1] == pytest.approx(depth, abs=EDGE / 4), (k, spread[k], depth)
        else:
            assert np.isnan(spread[k, 1])
        long_along = y_hi - y_lo < anchor_module.NARROW_M and far_x - near_x >= anchor_module.ALONG_ROAD_M
        assert narrow[k] == (len(c.voxel_points) > 0 and (thin or long_along))
        x = interquartile_mean(local[:, 0], w) if narrow[k] else near_x
        z = float((c.centroid - origin) @ rotation[:, 2])
        seen = (points[k] - origin) @ rotation  # the three sides in the vehicle frame
        assert seen == pytest.approx(np.array([[x, y_lo, z], [x, 0.5 * (y_lo + y_hi), z], [x, y_hi, z]]), abs=1e-9)
        assert far[k] == pytest.approx((far_x - x) * rotation[:, 0], abs=1e-9)
        assert side[k] == (2 if y_hi < 0 else 0 if y_lo > 0 else 1)


def test_a_narrow_clusters_range_moves_with_its_points_not_a_voxel_at_a_time() -> None:
    # a post's points pass from one layer of voxels to the next, a tenth of them a frame: the
    # middle half of their ranges then moves by at most 5 cm a frame over five frames, where their
    # median jumped the whole voxel (25 cm) in one
    post = surface((20.0, -0.25, 0.0), (20.5, 0.25, 1.5))
    near = (post.voxels[:, 0] + 0.5) * EDGE < 20.25
    xs = []
    for k in range(11):
        share = k / 10.0
        points = np.where(near, np.round(20 * (1 - share)), np.round(20 * share)).astype(np.int32)
        c = Cluster(**{**vars(post), "voxel_points": points})
        at, _, _, narrow, _, _ = anchors([c], np.array([c.centroid]), np.eye(4), EDGE)
        assert narrow[0]
        xs.append(float(at[0, 1, 0]))
    steps = np.diff(xs)
    assert xs[0] == pytest.approx(20.125, abs=1e-3) and xs[-1] == pytest.approx(20.375, abs=1e-3), xs
    assert np.all(steps > -1e-9) and steps.max() < 0.051 and (steps > 0.01).sum() >= 4, steps


def smeared(
    lo: tuple[float, float, float],
    hi: tuple[float, float, float],
    core_points: int,
    fringe_points: int | None = 1,
    fringe_m: float = 1.0,
) -> Cluster:
    """A box's voxels with ``core_points`` each, behind a fringe ``fringe_m`` deep of voxels holding ``fringe_points``.

    The fringe is stereo smear along the line of sight; ``None`` gives a cluster from a recording
    made before the mapper counted points per voxel.
    """
    core, fringe = surface(lo, hi), surface((lo[0] - fringe_m, lo[1], lo[2]), (lo[0], hi[1], hi[2]))
    points = np.concatenate([np.full(core.voxel_count, core_points), np.full(fringe.voxel_count, fringe_points or 0)])
    return Cluster(
        **{
            **vars(core),
            "voxels": np.concatenate([core.voxels, fringe.voxels]),
            "voxel_count": core.voxel_count + fringe.voxel_count,
            "voxel_points": points.astype(np.int32) if fringe_points is not None else np.zeros(0, np.int32),
        }
    )


def counted(voxels: np.ndarray, points: int = 20) -> Cluster:
    """A cluster of these voxels, each holding ``points`` of this frame's points."""
    return dataclasses.replace(of_voxels(voxels), voxel_points=np.full(len(voxels), points, dtype=np.int32))


def test_narrow_is_measured_across_the_line_of_sight() -> None:
    # an oncoming car left of the road, 15-19.3 m ahead: its front and the side facing the road
    # are in view. 1.8 m wide in y, but across the line of sight (22 degrees) it spans 3 m
    front = box_voxels((15.0, 6.1, 0.25), (15.25, 7.9, 1.5))
    side = box_voxels((15.0, 6.1, 0.25), (19.3, 6.35, 1.5))
    car = counted(np.unique(np.vstack([front, side]), axis=0))
    # a walker 35 degrees right, smeared 3 m along the line of sight: 1.7 m wide in y, 0.5 m across it
    ray = np.array([np.cos(np.radians(-35.0)), np.sin(np.radians(-35.0))])
    steps = [(r * ray[0], r * ray[1]) for r in np.arange(10.0, 13.0, 0.1)]
    smear = [box_voxels((x, y, 0.0), (x + 0.4, y + 0.4, 1.75)) for x, y in steps]
    walker = counted(np.unique(np.vstack(smear), axis=0))
    # a hedge along the right edge of the road, 10 m long: its near end is where the image's side cuts it
    hedge = counted(box_voxels((12.0, -7.5, 0.0), (22.0, -6.75, 1.5)))
    clusters = [car, walker, hedge]
    points, _, _, narrow, _, _ = anchors(clusters, np.array([c.centroid for c in clusters]), np.eye(4), EDGE)
    assert narrow.tolist() == [False, True, True]
    assert points[0, 0, 0] == pytest.approx(15.125, abs=0.01)  # the car's front, not its side's middle
    assert points[2, 1, 0] == pytest.approx(17.125, abs=0.3)  # the hedge's middle, not its cut near end


def test_a_narrow_cluster_is_followed_at_its_points_middle_range_a_wide_one_at_its_near_face() -> None:
    walker = smeared((20.0, -0.25, 0.0), (20.5, 0.25, 1.75), core_points=60)  # 0.5 m wide, 3 % of points in the fringe
    car = smeared((20.0, -4.0, 0.25), (24.0, -1.5, 1.5), core_points=60)  # 2.5 m wide
    old = smeared((20.0, -0.25, 0.0), (20.5, 0.25, 1.75), core_points=60, fringe_points=None)
    clusters = [walker, car, old]
    points, _, far, _, _, _ = anchors(clusters, np.array([c.centroid for c in clusters]), np.eye(4), EDGE)
    # the middle half of the points lies in the core's two layers (20.125 and 20.375 m), 26.6 % of
    # them in the first: their mean is 20.242 m, the core's middle less a centimetre of fringe
    assert points[0, 1, 0] == pytest.approx(20.242, abs=0.005)
    assert points[1, 2, 0] == pytest.approx(19.125, abs=0.01)  # the near face, fringe and all
    assert points[2, 1, 0] == pytest.approx(19.125, abs=0.01)  # without counts: the near face, as before
    assert points[0, 1, 0] + far[0, 0] == pytest.approx(20.375, abs=0.01)  # the far end stays the far end


@pytest.mark.parametrize("narrow_m", [2.0, 0.0])
def test_a_walker_coming_closer_inside_a_shrinking_smear_is_called_moving(
    narrow_m: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    # 1.5 m/s towards the camera from 30 m; the fringe before the walker shrinks by 1.5 m/s, so its
    # near face stands still (the case of urban-s2's walker 66). NARROW_M = 0: the near face only.
    monkeypatch.setattr(anchor_module, "NARROW_M", narrow_m)
    tracker, moving = new_tracker(), []
    for k in range(20):
        x = 30.0 - 0.15 * k
        walker = smeared((x, -0.25, 0.0), (x + 0.5, 0.25, 1.75), core_points=60, fringe_m=3.0 - 0.15 * k)
        (o,) = step(tracker, k, [walker]).obstacles
        moving.append(o.moving)
    if narrow_m > 0:
        assert all(moving[-4:]) and o.velocity[0] == pytest.approx(-1.5, abs=0.3), (moving, o.velocity)
    else:
        assert not any(moving) and abs(o.velocity[0]) < 0.5, (moving, o.velocity)


@pytest.mark.parametrize("upright_m", [Config().tracker.upright_m, 0.0])
def test_a_walker_whose_smear_swings_is_not_doubted_for_his_box_changing(upright_m: float) -> None:
    # 1.5 m/s towards the camera from 25 m inside a fringe 0.5-3 m deep that changes every frame:
    # his box's length swings by metres while the median of his points walks steadily. Without
    # the upright test (upright_m = 0) each swing is added to the noise of that median: moving from
    # frame 12 instead of 5 (from 15 while a narrow track's fringe still counted as slide).
    tracker, moving = new_tracker(upright_m=upright_m), []
    for k in range(20):
        x, fringe = 25.0 - 0.15 * k, 0.5 + 2.5 * abs(np.sin(1.2 * k))
        walker = smeared((x, -0.25, 0.0), (x + 0.5, 0.25, 1.75), core_points=60, fringe_m=fringe)
        walker = Cluster(**{**vars(walker), "bbox_min": np.array([x - fringe, -0.25, 0.0])})
        (o,) = step(tracker, k, [walker]).obstacles
        moving.append(o.moving)
    assert o.velocity[0] == pytest.approx(-1.5, abs=0.1)
    assert moving.index(True) <= 6 if upright_m > 0.0 else moving.index(True) >= 10, moving


def walker_and_post(tracker: Tracker, range_m: float, speed: float) -> tuple[list[bool], list[bool]]:
    """Moving labels of a walker crossing at ``speed`` and of a post, both ``range_m`` ahead in swinging smear.

    Smear stretches both narrow objects along the line of sight by 0.6-3.0 m and back, so their
    boxes grow and shrink along it; across it they keep their width.
    """
    walker_moving, post_moving = [], []
    for k in range(25):
        smear, smear_post = 0.6 + 2.4 * abs(np.sin(1.2 * k)), 0.6 + 2.4 * abs(np.sin(1.2 * k + 1.0))
        walker = cluster(
            0, (range_m + smear / 2, -3.0 + speed * 0.1 * k, 0.9), size=(smear, 0.6, 1.8), rgb=(0.2, 0.6, 0.2)
        )
        post = cluster(1, (range_m + smear_post / 2, 3.0, 1.5), size=(smear_post, 0.3, 3.0), rgb=(0.3, 0.3, 0.6))
        by_side = sorted(step(tracker, k, [walker, post]).obstacles, key=lambda o: o.centroid[1])
        assert len(by_side) == 2, k
        walker_moving.append(by_side[0].moving)
        post_moving.append(by_side[1].moving)
    return walker_moving, post_moving


@pytest.mark.parametrize("narrow_m", [2.0, 0.0])
def test_a_walker_crossing_inside_a_swinging_smear_is_moving_by_its_bearing(narrow_m: float) -> None:
    # tracker.narrow_across_m = 0: the whole velocity only. Both are upright; their label is held
    # to moving_sigma_k here, so that only the bearing differs.
    tracker = new_tracker(narrow_across_m=narrow_m, upright_sigma_k=Config().tracker.moving_sigma_k)
    walker_moving, post_moving = walker_and_post(tracker, 15.0, 1.4)
    assert not any(post_moving)
    if narrow_m > 0:
        assert walker_moving.index(True) <= 4 and sum(walker_moving) >= 20, walker_moving
    else:
        assert walker_moving.index(True) >= 6 and sum(walker_moving) <= 16, walker_moving


def test_an_upright_track_is_called_moving_at_fewer_sigmas_and_a_post_still_is_not() -> None:
    # slower and further than above, judged by the whole velocity only, with a car's process noise so
    # that only the sigmas differ (an upright track's 2 m/s^2 lets this smear's 2.4 m swing along the
    # line of sight into the whole velocity: 5 frames moving instead of 13; the bearing, which the
    # tracker uses for narrow tracks, is the test above)
    frames = {}
    for sigma_k in (Config().tracker.upright_sigma_k, Config().tracker.moving_sigma_k):
        tracker = new_tracker(narrow_across_m=0.0, upright_sigma_k=sigma_k, upright_process_noise=0.0)
        walker_moving, post_moving = walker_and_post(tracker, 18.0, 1.2)
        assert not any(post_moving)
        frames[sigma_k] = sum(walker_moving)
    upright, car = frames.values()
    assert upright >= 10 and upright >= car + 5  # 15 and 9 of 25 frames (6 at a 0.55 m/s threshold)


def walker_trailing_a_fringe(k: int, x0: float, speed: float) -> Cluster:
    """A walker at ``x0 + speed * t`` along the line of sight, trailed by a fringe of stray voxels
    that swings between 0.25 and 3 m long behind him: dense points on the walker, one per fringe voxel."""
    x = x0 + speed * 0.1 * k
    core = box_voxels((x, -0.25, 0.0), (x + 0.5, 0.25, 1.75))
    length = 0.25 + 2.75 * abs(np.sin(0.5 * k))
    fringe = box_voxels((x + 0.75, -0.25, 0.5), (x + 0.75 + length, 0.25, 1.0))  # from the voxel after his
    c = of_voxels(np.concatenate([core, fringe]).astype(np.int32), rgb=(0.2, 0.6, 0.2))
    points = np.concatenate([np.full(len(core), 20, np.int32), np.ones(len(fringe), np.int32)])
    return Cluster(**{**vars(c), "voxel_points": points})


def test_a_narrow_walker_trailing_a_swinging_fringe_is_moving_and_a_post_with_one_is_not() -> None:
    # his box swings by up to 2.75 m along the line of sight, which would drag a near face; he is
    # followed at his points' middle range, which the fringe's few points hardly move, so only
    # growth across the line of sight is taken as slide for a narrow track
    labels = {}
    for name, speed in (("walker", 1.4), ("post", 0.0)):
        tracker = new_tracker()
        labels[name] = [
            any(o.moving for o in step(tracker, k, [walker_trailing_a_fringe(k, 15.0, speed)]).obstacles)
            for k in range(25)
        ]
    assert not any(labels["post"]), labels["post"]
    # 20 of 25 frames from frame 5 on; with the fringe taken as slide, 14 from frame 7, with gaps
    assert labels["walker"].index(True) <= 6 and sum(labels["walker"]) >= 18, labels["walker"]


def walker_crossing_an_oblique_ray(k: int, speed: float, bearing_deg: float = 20.0, r0: float = 18.0) -> Cluster:
    """A walker ``bearing_deg`` off the vehicle's axis crossing his line of sight at ``speed``, trailed along
    that line by a fringe of stray voxels swinging between 0.5 and 3.5 m long; dense points on him."""
    u = np.array([np.cos(np.radians(bearing_deg)), np.sin(np.radians(bearing_deg)), 0.0])
    at = u * r0 + np.array([-u[1], u[0], 0.0]) * speed * 0.1 * k
    core = box_voxels((at[0] - 0.25, at[1] - 0.25, 0.0), (at[0] + 0.25, at[1] + 0.25, 1.75))
    reach = np.arange(0.5, 1.0 + 3.0 * abs(np.sin(0.5 * k)), EDGE / 2)
    trail = at[None, :] + reach[:, None] * (at / np.linalg.norm(at))[None, :]
    fringe = np.unique(
        np.concatenate([np.floor(np.column_stack([trail[:, 0:2], np.full(len(reach), z)]) / EDGE) for z in (0.6, 0.9)]),
        axis=0,
    ).astype(np.int32)
    fringe = fringe[~(fringe[:, None, :] == core[None, :, :]).all(axis=2).any(axis=1)]
    c = of_voxels(np.concatenate([core, fringe]), rgb=(0.2, 0.6, 0.2))
    points = np.concatenate([np.full(len(core), 20, np.int32), np.ones(len(fringe), np.int32)])
    return Cluster(**{**vars(c), "voxel_points": points})


def test_a_walker_on_an_oblique_ray_is_narrow_by_his_points_not_his_box() -> None:
    # 20 degrees off the axis, his smear along the ray makes his box 3-4 m long in x and 1.5-2 m in
    # y: 2-3 m across his line of sight, so by his box he is no narrow track, his motion across it
    # is not looked at and the box's swing counts as slide. His points are 0.5 m wide across it, and
    # their middle half is 0.5 m deep along it: by them he is narrow, and called moving.
    labels = {}
    for by_points in (True, False):
        for name, speed in (("walker", 1.4), ("post", 0.0)):
            tracker = new_tracker(narrow_by_points=by_points)
            labels[by_points, name] = [
                any(o.moving for o in step(tracker, k, [walker_crossing_an_oblique_ray(k, speed)]).obstacles)
                for k in range(25)
            ]
    assert not any(labels[True, "post"]) and not any(labels[False, "post"])
    # measured: 16 of 25 frames from frame 6 on by his points, 5 by his box
    assert labels[True, "walker"].index(True) <= 7 and sum(labels[True, "walker"]) >= 13, labels[True, "walker"]
    assert sum(labels[False, "walker"]) <= 8, labels[False, "walker"]


def test_a_speed_bound_along_a_direction_ignores_the_scatter_across_it() -> None:
    times = np.tile(np.arange(8) * 0.1, (2, 1))
    along_y = np.stack([np.array([0.0, 0.6, -0.6, 0.6, -0.6, 0.6, -0.6, 0.0]), 1.4 * times[0]], axis=1)
    points = np.stack([along_y, along_y])
    count = np.array([8, 8])
    both, across = speed_bounds(points, times, count, 0.15, 1.5, direction=np.array([[0.0, 1.0], [1.0, 0.0]]))
    assert both[0] < Config().tracker.moving_on_mps  # x scatters by 0.6 m: not enough to call 1.4 m/s moving
    assert across[0] == pytest.approx(1.4 - 1.5 * 0.15 / np.sqrt(0.42), abs=1e-6)  # only the floor's doubt along y
    assert across[1] < 0.0  # along x the same points say nothing


def test_merged_pieces_keep_their_point_counts_voxel_for_voxel() -> None:
    a, b = surface((20.0, -0.25, 0.0), (20.5, 0.25, 1.75)), surface((20.5, -0.25, 0.0), (21.0, 0.25, 1.75), cid=1)
    a = Cluster(**{**vars(a), "voxel_points": np.full(a.voxel_count, 7, np.int32)})
    b = Cluster(**{**vars(b), "voxel_points": np.arange(b.voxel_count, dtype=np.int32)})
    both = merge([a, b], EDGE)
    assert both.voxel_points.tolist() == [7] * a.voxel_count + list(range(b.voxel_count))
    assert merge([a, Cluster(**{**vars(b), "voxel_points": np.zeros(0, np.int32)})], EDGE).voxel_points.size == 0


def test_object_crossing_the_line_of_sight_keeps_its_lateral_speed() -> None:
    # the followed face changes (right face, middle, left face) with no jump in the state
    tracker = new_tracker()
    for k in range(40):
        y = -4.0 + 2.0 * k * 0.1  # a car 4.5 m long driving across, 2 m/s
        out = step(tracker, k, [surface((12.0, y - 2.25, 0.25), (14.0, y + 2.25, 1.5))])
        if k >= 10:
            (o,) = out.obstacles
            assert o.moving and abs(o.velocity[1] - 2.0) < 0.3 and abs(o.velocity[0]) < 0.3, k


def test_pieces_of_a_known_object_stay_one_track() -> None:
    # a car tracked whole, then split by colour into body and windows that change from frame to frame
    tracker = new_tracker()
    for k in range(5):
        out = step(tracker, k, [surface((15.0, -1.0, 0.25), (19.5, 1.0, 1.5))])
    (car,) = [o for o in out.obstacles if o.state == "tracked"]
    rng = np.random.default_rng(8)
    for k in range(5, 25):
        cut = rng.uniform(15.5, 19.0)
        body = surface((15.0, -1.0, 0.25), (cut, 1.0, 1.5), 0)
        windows = surface((cut, -1.0, 0.25), (19.5, 1.0, 1.5), 1, (0.2, 0.2, 0.6))
        out = step(tracker, k, [body, windows])
        assert [o.id for o in out.obstacles] == [car.id], k
        assert not out.obstacles[0].moving
    assert tracker.counters["tracks_born"] == 1


def test_only_pieces_chained_by_narrow_gaps_are_gathered() -> None:
    boxes = np.array([[0.0, 0.0, 0.0], [1.05, 0.0, 0.0], [2.0, 0.0, 0.0], [3.2, 0.0, 0.0]])
    parts = components(near_boxes(boxes, boxes + 1.0, 0.1))  # gaps 0.05, overlapping, 0.2 m
    assert [p.tolist() for p in parts] == [[0, 1, 2], [3]]


@pytest.mark.parametrize("gap", [0.1, -1.0])
def test_walkers_who_part_from_one_blob_get_a_track_each(gap: float) -> None:
    # two walkers side by side are one cluster while stereo smear joins them, then 1 m of air parts
    # them; every piece in the blob's old box used to be gathered back into it, for ever
    tracker = new_tracker(fragment_gap=gap)
    for k in range(6):
        out = step(tracker, k, [surface((15.0, -1.5, 0.0), (15.5, 0.5, 1.75))])
    for k in range(6, 16):
        left = surface((15.0, -1.5, 0.0), (15.5, -1.0, 1.75), 0)
        right = surface((15.0, 0.0, 0.0), (15.5, 0.5, 1.75), 1, (0.2, 0.5, 0.2))
        out = step(tracker, k, [left, right])
    tracked = [o for o in out.obstacles if o.state == "tracked"]
    assert len(tracked) == (2 if gap >= 0.0 else 1)


def test_pieces_touch_by_a_corner_but_not_across_a_voxel_of_air_and_by_their_columns() -> None:
    a = np.array([[0, 0, 0], [1, 0, 0]])
    corner, apart, far = np.array([[2, 1, 1]]), np.array([[3, 0, 0]]), np.array([[9, 9, 9]])
    touch = in_contact([a, corner, apart, far], np.ones((4, 4), dtype=bool))
    assert touch[0].tolist() == [True, True, False, False]
    assert touch[1, 2] and touch[2, 1]  # (2, 1, 1) and (3, 0, 0) are diagonal neighbours
    assert not in_contact([a, corner], np.eye(2, dtype=bool))[0, 1]  # not a candidate: not tested
    # a car's sill and roof edge, two voxels of window apart in height, stand in the same columns
    sill, roof = np.array([[5, 0, 1], [6, 0, 1]]), np.array([[6, 0, 4], [7, 0, 4]])
    assert not in_contact([sill, roof], np.ones((2, 2), dtype=bool))[0, 1]
    assert in_contact([footprint(sill), footprint(roof)], np.ones((2, 2), dtype=bool))[0, 1]


@pytest.mark.parametrize("standing_m", [0.3, -1.0])
def test_a_walker_parting_inside_the_box_of_a_facade_and_a_pole_gets_a_track(standing_m: float) -> None:
    # synthetic urban seed 7: the voxel map joined a facade, a pole 2.3 m in front of it and a
    # walker between them into one cluster. Once the walker is a cluster of its own, its box
    # still lies inside the blob's, and it touches the blob's box everywhere but no voxel of it.
    tracker = new_tracker(fragment_standing_m=standing_m)
    wall = box_voxels((20.0, -7.25, 0.0), (28.0, -7.0, 3.0))
    pole = box_voxels((23.0, -4.75, 0.0), (23.25, -4.5, 3.5))

    def walker(k: int) -> np.ndarray:
        x = 26.0 - 0.15 * k  # 1.5 m/s toward the vehicle
        return box_voxels((x, -6.0, 0.0), (x + 0.5, -5.5, 1.75))

    for k in range(6):
        out = step(tracker, k, [of_voxels(np.vstack([wall, pole, walker(k)]), 0, (0.5, 0.5, 0.5))])
    for k in range(6, 22):
        blob = of_voxels(np.vstack([wall, pole]), 0, (0.5, 0.5, 0.5))
        out = step(tracker, k, [blob, of_voxels(walker(k), 1, (0.5, 0.2, 0.2))])
    tracked = [o for o in out.obstacles if o.state == "tracked"]
    walkers = [o for o in tracked if abs(o.centroid[1] + 5.75) < 0.3 and o.volume < 1.0]
    if standing_m >= 0.0:
        (w,) = walkers
        assert w.moving and abs(w.velocity[0] + 1.5) < 0.4, w.velocity
    else:
        assert walkers == [] and len(tracked) == 1  # gathered back into the blob, frame after frame


@pytest.mark.parametrize("alone_mps", [Config().tracker.upright_alone_mps, 0.0])
def test_a_walker_brushing_along_a_low_wall_is_not_gathered_into_its_track(alone_mps: float) -> None:
    # synthetic urban: walkers pass bins 0.1 m apart on the sidewalk; here a wall 1 m high, so that
    # he stays beside it. Once he is a cluster of his own, his footprint still touches the wall's
    # and he lies in the box of the wall's track, which took them both while they were one cluster.
    tracker = new_tracker(upright_alone_mps=alone_mps)
    wall = box_voxels((20.0, -5.0, 0.0), (26.0, -4.5, 1.0))

    def walker(k: int) -> np.ndarray:
        x = 25.5 - 0.15 * k  # 1.5 m/s toward the vehicle
        return box_voxels((x, -5.5, 0.0), (x + 0.5, -5.0, 1.75))

    for k in range(6):
        out = step(tracker, k, [of_voxels(np.vstack([wall, walker(k)]), 0, (0.5, 0.5, 0.5))])
    for k in range(6, 22):
        out = step(tracker, k, [of_voxels(wall, 0, (0.5, 0.5, 0.5)), of_voxels(walker(k), 1, (0.5, 0.2, 0.2))])
    tracked = [o for o in out.obstacles if o.state == "tracked"]
    walkers = [o for o in tracked if abs(o.centroid[1] + 5.25) < 0.3 and o.volume < 1.0]
    if alone_mps > 0.0:
        (w,) = walkers
        assert w.moving and abs(w.velocity[0] + 1.5) < 0.4, w.velocity
    else:
        assert walkers == [] and len(tracked) == 1  # gathered into the wall's track, frame after frame


def test_an_upright_piece_stays_apart_in_a_slow_tracks_box_and_is_gathered_in_a_fast_ones() -> None:
    # a vehicle's track is left out of the rule: a car's tall piece can be as thin as a walker
    low = of_voxels(box_voxels((20.0, -5.0, 0.0), (22.0, -4.5, 1.0)), 0)
    upright = of_voxels(box_voxels((21.0, -5.5, 0.0), (21.5, -5.0, 1.75)), 1)
    cfg = Config().tracker
    rule = Standing(cfg.fragment_standing_m, cfg.upright_m, cfg.upright_thin_m, alone_mps=3.0)
    lo, hi = np.array([[19.5, -6.0, 0.0]]), np.array([[22.5, -4.0, 2.0]])
    sight = Sight(np.zeros(3), EDGE)
    assert len(gather([low, upright], lo, hi, 0.25, EDGE, 0.1, rule, sight, np.array([0.0]))) == 2  # a bin's track
    assert len(gather([low, upright], lo, hi, 0.25, EDGE, 0.1, rule, sight, np.array([9.0]))) == 1  # a car's
    assert len(gather([low, upright], lo, hi, 0.25, EDGE, 0.1, dataclasses.replace(rule, alone_mps=0.0), sight)) == 1


@pytest.mark.parametrize("thin_m", [Config().tracker.upright_thin_m, 0.0])
def test_walkers_crossing_abreast_whose_smears_touch_get_a_track_each(thin_m: float) -> None:
    # synthetic crossing: walkers two abreast, 1 m apart in range, each smeared 2 m along the line
    # of sight, so their footprints touch column to column; one blob first, then a cluster each
    tracker = new_tracker(upright_thin_m=thin_m)

    def walkers(k: int) -> tuple[np.ndarray, np.ndarray]:
        y = -3.0 + 0.15 * k  # 1.5 m/s across the road
        near = box_voxels((20.0, y, 0.0), (22.0, y + 0.5, 1.75))
        return near, box_voxels((21.0, y + 0.5, 0.0), (23.0, y + 1.0, 1.75))

    for k in range(6):
        out = step(tracker, k, [of_voxels(np.vstack(walkers(k)), 0, (0.5, 0.5, 0.5))])
    for k in range(6, 22):
        near, far = walkers(k)
        out = step(tracker, k, [of_voxels(near, 0, (0.6, 0.2, 0.2)), of_voxels(far, 1, (0.2, 0.2, 0.6))])
    tracked = sorted((o for o in out.obstacles if o.state == "tracked"), key=lambda o: o.centroid[0])
    if thin_m > 0.0:
        assert [round(o.centroid[0]) for o in tracked] == [21, 22]
    else:
        assert len(tracked) == 1  # gathered into the blob's track, frame after frame


def smear_along_sight(range_m: float, bearing: float, across_m: float, length_m: float = 3.0) -> np.ndarray:
    """The voxels of a walker 0.5 m wide and 1.75 m tall, smeared ``length_m`` along the line of sight."""
    ray, normal = np.array([np.cos(bearing), np.sin(bearing)]), np.array([-np.sin(bearing), np.cos(bearing)])
    s, w, z = np.meshgrid(np.arange(0, length_m, 0.1), np.arange(0, 0.5, 0.1), np.arange(0, 1.75, 0.1), indexing="ij")
    xy = (range_m + s.ravel())[:, None] * ray + (across_m + w.ravel())[:, None] * normal
    points = np.column_stack([xy, z.ravel()])
    return np.unique(np.floor(points / EDGE).astype(np.int32), axis=0)


def test_a_walker_smeared_along_an_oblique_line_of_sight_is_upright_seen_from_the_camera() -> None:
    # at 30 degrees off the axis a 3 m smear makes a 2.6 x 2.0 m box: by its box no person
    walker = of_voxels(smear_along_sight(20.0, np.radians(30.0), 0.0))
    extent = walker.bbox_max - walker.bbox_min
    assert extent[0:2].min() > 1.5
    standing, on_floor = Config().tracker, np.array([True])
    rule = Standing(standing.fragment_standing_m, standing.upright_m, standing.upright_thin_m)
    assert not rule.whole([walker], on_floor)[0]
    assert rule.whole([walker], on_floor, Sight(np.zeros(3), EDGE))[0]
    assert Sight(np.zeros(3), EDGE).width(walker.voxels) < 1.0


def test_walkers_abreast_on_an_oblique_line_of_sight_get_a_track_each() -> None:
    # synthetic urban: a walker on the pavement 1 m in front of a wall at 20-30 m, his smear
    # touching the wall's; here two walkers abreast, 30 degrees off the axis, their smears touching
    tracker = new_tracker()
    bearing = np.radians(20.0)

    def counted(voxels: np.ndarray, cid: int, rgb: tuple[float, float, float]) -> Cluster:
        c = of_voxels(voxels, cid, rgb)
        return dataclasses.replace(c, voxel_points=np.full(c.voxel_count, 8, dtype=np.int32))

    for k in range(6):
        both = np.vstack(
            [smear_along_sight(20.0, bearing, -0.15 * k, 3.5), smear_along_sight(21.0, bearing, 0.6 - 0.15 * k, 3.5)]
        )
        out = step(tracker, k, [counted(np.unique(both, axis=0), 0, (0.5, 0.5, 0.5))])
    for k in range(6, 22):
        near, far = (
            smear_along_sight(20.0, bearing, -0.15 * k, 3.5),
            smear_along_sight(21.0, bearing, 0.6 - 0.15 * k, 3.5),
        )
        out = step(tracker, k, [counted(near, 0, (0.6, 0.2, 0.2)), counted(far, 1, (0.2, 0.2, 0.6))])
    tracked = [o for o in out.obstacles if o.state == "tracked"]
    assert len(tracked) == 2 and all(o.moving for o in tracked)


def test_a_car_standing_in_two_pieces_of_its_length_stays_one_track() -> None:
    # a car in two colours split across its length: both pieces stand and are as tall as a walker,
    # but each is the car's width across, so they are gathered as before
    tracker = new_tracker()
    for k in range(5):
        out = step(tracker, k, [surface((15.0, -1.0, 0.0), (19.5, 1.0, 1.5))])
    (car,) = [o for o in out.obstacles if o.state == "tracked"]
    for k in range(5, 15):
        front = surface((15.0, -1.0, 0.0), (17.0, 1.0, 1.5), 0)
        back = surface((17.0, -1.0, 0.0), (19.5, 1.0, 1.5), 1, (0.2, 0.2, 0.6))
        out = step(tracker, k, [front, back])
        assert [o.id for o in out.obstacles] == [car.id], k


def test_a_crown_apart_from_its_trunk_stays_one_track() -> None:
    # a tree seen split by colour into trunk and crown, voxels a step apart: the crown, held 1.5 m
    # up, cannot stand alone, so it is gathered by its box as before (KITTI tracking 0001's hedges
    # and trees, cut into pieces that swap from frame to frame, were called moving otherwise)
    tracker = new_tracker()
    trunk = box_voxels((15.0, 5.0, 0.0), (15.5, 5.5, 2.0))
    crown = box_voxels((14.0, 4.0, 1.5), (16.5, 6.5, 4.0))
    hollow = (crown[:, 2] < 10) & (crown[:, 0] >= 57) & (crown[:, 0] < 64) & (crown[:, 1] >= 17) & (crown[:, 1] < 24)
    crown = crown[~hollow]  # a 0.5 m shell of air round the trunk's top
    for k in range(5):
        out = step(tracker, k, [of_voxels(np.vstack([trunk, crown]), 0, (0.2, 0.3, 0.1))])
    (tree,) = [o for o in out.obstacles if o.state == "tracked"]
    for k in range(5, 20):
        out = step(tracker, k, [of_voxels(trunk, 0, (0.3, 0.2, 0.1)), of_voxels(crown, 1, (0.2, 0.4, 0.1))])
        assert [o.id for o in out.obstacles] == [tree.id], k
    assert tracker.counters["tracks_born"] == 1


def test_a_cluster_that_changes_shape_does_not_give_a_static_object_speed() -> None:
    # 25 m ahead the centroid is good to 0.15 m across the line of sight; from frame 12 on the
    # cluster takes in a piece of its neighbour and its centroid steps 0.8 m sideways for good
    rng = np.random.default_rng(9)
    tracker = new_tracker()
    for k in range(30):
        centre = np.array([25.0, 1.0, 0.75]) + rng.normal(scale=0.05, size=3)
        centre[1] += 0.8 * (k >= 12)
        out = step(tracker, k, [cluster(0, centre, size=(1.0, 1.0, 1.5))])
        (o,) = out.obstacles
        assert not o.moving and (k < 12 or o.speed < 0.3), (k, o.speed)
    assert tracker.counters["tracks_born"] == 1


def test_faces_that_stop_sliding_are_called_stationary_within_the_window() -> None:
    # a hedge right of the road, 36-42 m ahead, whose visible stretch slides toward the vehicle at
    # 6 m/s for 0.8 s (a parked car in front uncovers it at one end and hides it at the other)
    # and then stands still. The filter's velocity lags (2.8 m/s a further 0.7 s on); on KITTI
    # tracking 0001 such tracks were called moving for 10-20 frames after their faces had stopped.
    cfg = Config()
    cfg.volume.x_max, cfg.volume.y_half = 45.0, 10.0  # KITTI's volume
    tracker = Tracker.from_config(cfg)
    rng = np.random.default_rng(3)
    labels = []
    for k in range(30):
        near = 42.0 - 0.6 * min(k, 8) + rng.normal(scale=0.2)
        (o,) = step(tracker, k, [surface((near, -7.5, 0.25), (near + 3.0, -6.0, 1.5))]).obstacles
        labels.append(o.moving)
    assert any(labels[:9])  # while it slides it is indistinguishable from a mover
    assert not any(labels[8 + 8 :]), labels  # once the window holds only stopped faces: stationary


def test_oncoming_car_seen_with_range_noise_is_called_moving_within_seven_frames() -> None:
    # 35 m ahead, closing at 6 m/s over ground; both ends of it move, each by 0.6 m a frame, with
    # the range noise of stereo at that distance (0.5 m) on top
    rng = np.random.default_rng(4)
    cfg = Config()
    cfg.volume.x_max, cfg.volume.y_half = 45.0, 10.0  # KITTI's volume: 35 m is inside it
    tracker = Tracker.from_config(cfg)
    labelled = []
    for k in range(12):
        front = 35.0 - 0.6 * k + rng.normal(scale=0.5)
        out = step(tracker, k, [surface((front, 3.0, 0.25), (front + 4.0, 4.75, 1.5))])
        labelled += [o.moving for o in out.obstacles]
    assert any(labelled[:8]), labelled


def test_a_cluster_that_sheds_a_merged_neighbour_forgets_the_faces_of_the_blob() -> None:
    # a parked car 12 m ahead, right of the road, merged for five frames with a hedge across 6 m;
    # then the car alone (2 m wide): the side faces before and after are of two different shapes,
    # and a line through them would read a lateral speed (KITTI tracking 0001, frames 5-9)
    tracker = new_tracker()
    blob, car = surface((11.0, -4.0, 0.25), (15.0, 2.0, 1.5)), surface((11.0, -4.0, 0.25), (14.0, -2.0, 1.5))
    for k in range(5):
        step(tracker, k, [blob])
    assert tracker.tracks.window_n[0] == 5
    step(tracker, 5, [car])
    assert tracker.tracks.window_n[0] == 1  # the window starts again from the car's own face
    labels = [o.moving for k in range(6, 16) for o in step(tracker, k, [car]).obstacles]
    assert not any(labels)


def test_a_moving_track_keeps_its_faces_through_a_change_of_shape() -> None:
    # its label rests on the window: a lorry whose cluster loses its trailer half is still moving
    tracker = new_tracker()
    for k in range(10):
        x = 15.0 + 1.0 * k  # 10 m/s away from the parked vehicle
        step(tracker, k, [surface((x, 2.0, 0.25), (x + 8.0, 4.5, 3.0))])
    (o,) = step(tracker, 10, [surface((25.0, 2.0, 0.25), (29.0, 4.5, 3.0))]).obstacles
    assert o.moving and tracker.tracks.window_n[0] > 1


@pytest.mark.parametrize("found_m", [0.3, 1.5])
def test_a_ghost_found_again_metres_from_its_prediction_starts_its_speed_window_again(found_m: float) -> None:
    # synthetic urban seed 1: a young track lost for four frames was given a standing walker 3 m
    # beyond it, read the step as 6 m/s, and its speed window, spanning the gap, agreed
    tracker = new_tracker()
    for k in range(3):
        out = step(tracker, k, [surface((40.0, -5.0, 0.0), (40.5, -4.5, 1.75))])
    for k in range(3, 6):
        out = step(tracker, k, [])
    assert [o.state for o in out.obstacles] == ["ghost"]
    out = step(tracker, 6, [surface((40.0 + found_m, -5.0, 0.0), (40.5 + found_m, -4.5, 1.75))])
    assert [o.state for o in out.obstacles] == ["tracked"]
    restarted = found_m > Config().tracker.revive_restart_m
    assert tracker.tracks.window_n.tolist() == ([1] if restarted else [4])


@pytest.mark.parametrize("growth_m", [0.0, 2.0])
def test_a_car_whose_cluster_takes_in_a_neighbour_keeps_its_own_box(growth_m: float) -> None:
    # synthetic slope seed 10: a lead car's cluster joined an oncoming car's for one frame, 3 m
    # wider, and the obstacle was reported on the pair's centroid, 2.2 m sideways
    tracker = new_tracker(merge_growth_m=growth_m)
    for k in range(8):
        x = 20.0 + 1.0 * k
        out = step(tracker, k, [surface((x, -1.0, 0.25), (x + 4.5, 1.0, 1.5))])
    (car,) = out.obstacles
    x = 28.0
    (merged,) = step(tracker, 8, [surface((x, -1.0, 0.25), (x + 4.5, 4.25, 1.5))]).obstacles
    assert merged.id == car.id
    sideways = merged.centroid[1] - car.centroid[1]
    if growth_m > 0.0:
        assert abs(sideways) < 0.3 and merged.bbox_max[1] < 1.5
        assert merged.centroid[0] - car.centroid[0] == pytest.approx(1.0, abs=0.3)  # carried by the filter
    else:
        assert sideways > 1.0  # the pair's centroid
    (alone,) = step(tracker, 9, [surface((29.0, -1.0, 0.25), (33.5, 1.0, 1.5))]).obstacles
    assert abs(alone.centroid[1]) < 0.3 and alone.moving


def test_a_new_walker_track_starts_with_a_walkers_speed_prior_and_a_car_with_a_cars() -> None:
    tracker = new_tracker()
    walker = surface((20.0, -5.0, 0.0), (20.5, -4.5, 1.75))
    car = surface((15.0, 2.0, 0.0), (19.5, 4.0, 1.5))
    counted = [dataclasses.replace(c, voxel_points=np.full(c.voxel_count, 8, dtype=np.int32)) for c in (walker, car)]
    step(tracker, 0, counted)
    cfg = Config().tracker
    assert np.sqrt(tracker.tracks.p[:, 3, 3]).tolist() == pytest.approx(
        [cfg.upright_initial_speed_std, cfg.initial_speed_std]
    )
    # so a walker's first change of cluster (a smear piece beside him, then him, 1 m apart) is
    # read as less speed
    first: list[float] = []
    for std in (cfg.upright_initial_speed_std, cfg.initial_speed_std):
        tracker = new_tracker(upright_initial_speed_std=std)
        for k, y in enumerate((-4.0, -5.0)):
            piece = surface((20.0, y, 0.0), (20.5, y + 0.5, 1.75))
            out = step(tracker, k, [dataclasses.replace(piece, voxel_points=np.full(piece.voxel_count, 8, np.int32))])
        first.append(out.obstacles[0].speed)
    assert first[0] < first[1] - 0.5


@pytest.mark.parametrize("near_only_m", [0.0, Config().tracker.upright_near_only_m])
def test_a_walker_whose_far_smear_swings_is_confirmed_moving_by_his_near_face(near_only_m: float) -> None:
    # the far end of a walker's cluster is the far fringe of his smear, 0.5-3 m deep from frame
    # to frame: a line through it scatters too much to confirm anything
    tracker = new_tracker(upright_near_only_m=near_only_m)
    labels = []
    for k in range(16):
        x = 15.0 + 0.15 * k  # walking away at 1.5 m/s
        depth = 0.5 + 2.5 * abs(np.sin(1.3 * k))
        core, fringe = (
            box_voxels((x, -3.0, 0.0), (x + 0.5, -2.5, 1.75)),
            box_voxels((x + 0.5, -3.0, 0.0), (x + 0.5 + depth, -2.5, 1.75)),
        )
        walker = of_voxels(np.vstack([core, fringe]))
        points = np.concatenate([np.full(len(core), 8), np.full(len(fringe), 1)]).astype(np.int32)
        (o,) = step(tracker, k, [dataclasses.replace(walker, voxel_points=points)]).obstacles
        labels.append(o.moving)
    moving = sum(labels[8:])
    # 8 of the last 8 frames, against 2 when the far fringe must line up as well (0 while the
    # fringe's growth also counted as slide, when the near face alone gave 6)
    assert moving >= 6 if near_only_m > 0.0 else moving <= 2


def test_a_walker_starting_from_the_kerb_is_followed_sooner_with_an_upright_process_noise() -> None:
    # waits 8 frames, then crosses at 1.5 m/s; a car's process noise (1 m/s^2) lags him for longer
    def speeds(upright_noise: float) -> list[float]:
        # the filter alone: the reported velocity's blend with the faces' line would hide the difference
        tracker = new_tracker(upright_process_noise=upright_noise, velocity_faces=0)
        out = []
        for k in range(16):
            y = -5.0 + 0.15 * max(k - 8, 0)
            result = step(tracker, k, [counted(box_voxels((15.0, y, 0.0), (15.5, y + 0.5, 1.75)))])
            out.append(float(np.linalg.norm(result.obstacles[0].velocity[0:2])))
        return out

    car_like, upright = speeds(0.0), speeds(2.0)
    assert max(upright[:8]) < 0.3  # standing still: no speed either way
    assert upright[13] > 1.0 > car_like[13]  # five frames after he set off


def test_a_slice_reaching_in_from_the_side_is_unsure_along_the_road_too() -> None:
    volume = Config().volume  # |y| <= 8.2 m
    lo = np.array([[12.0, 7.2, 0.0], [12.0, 6.1, 0.0], [25.0, -1.0, 0.0]])
    hi = np.array([[15.0, 8.2, 1.5], [16.5, 8.2, 1.5], [28.7, 1.0, 1.5]])
    cov = cut_covariance(lo, hi, np.eye(4), volume, EDGE, slice_m=1.75)
    assert cov[0, 0, 0] == pytest.approx(9.0) and cov[0, 1, 1] == pytest.approx(1.0)  # a slice 1 m deep
    assert cov[1, 0, 0] == 0.0 and cov[1, 1, 1] == pytest.approx(2.1**2)  # a car 2.1 m in: only across
    assert cov[2, 0, 0] == pytest.approx(3.7**2) and cov[2, 1, 1] == 0.0  # cut by the far end


def test_a_slice_whose_ends_slide_along_the_road_is_not_called_moving_for_a_second() -> None:
    # a hedge beyond the volume's side, seen as a 1 m deep slice whose ends slide 0.4 m a frame; a
    # slide kept up for longer is believed in the end (KITTI's slices last a few frames)
    def moving(slice_m: float) -> list[bool]:
        tracker = new_tracker(side_slice_m=slice_m)
        out = []
        for k in range(20):
            x = 12.0 + 0.4 * k
            result = step(tracker, k, [counted(box_voxels((x, 7.25, 0.0), (x + 3.0, 8.2, 1.5)))])
            out.append(any(o.moving for o in result.obstacles))
        return out

    assert moving(0.0).index(True) <= 4
    assert not any(moving(Config().tracker.side_slice_m)[:10])


def test_the_benchmark_times_a_revision_beside_this_tree_on_the_same_frames() -> None:
    # against HEAD: with the tracker as committed (CI's clean clone) the two must agree exactly
    out = compare("HEAD", objects=10, frames=15, repeats=1)
    assert out["cpu_ms"] > 0.0 and out["against_cpu_ms"] > 0.0 and out["ratio"] > 0.0
    diff = ["git", "-C", str(REPO), "diff", "--quiet", "HEAD", "--", "services/tracker"]
    if subprocess.run(diff).returncode == 0:
        assert out["same_output"]
    with pytest.raises(SystemExit, match="no services/tracker"):
        compare("no-such-revision", objects=2, frames=12, repeats=1)


# ------------------------------------------------------------------ left behind


def footprints_after(pieces_by_frame: list[tuple[list[Cluster], int]], frames: int = 2) -> list[bool]:
    """Per frame: whether track 7, taking piece ``index`` of that frame's pieces, slid off what it followed."""
    left = LeftBehind(frames)
    out = []
    for pieces, index in pieces_by_frame:
        rows = np.array([0])
        obs, _, _ = observe(pieces, np.eye(4), EDGE)
        out.append(len(left.slid(np.array([7]), rows, np.array([index]), obs, pieces, np.array([False]), EDGE)) == 1)
    return out


def test_a_track_whose_old_footprint_another_cluster_holds_slid() -> None:
    wall = [surface((30.0 + 1.5 * i, 6.0, 0.0), (31.0 + 1.5 * i, 6.5, 0.75), cid=i) for i in range(4)]
    # the track hops one piece along per frame while every piece stands where it was
    assert footprints_after([(wall, i) for i in range(4)]) == [False, False, True, True]


def test_a_moving_object_leaves_its_footprint_empty_or_covers_it_itself() -> None:
    moving = [([surface((20.0 + 1.0 * k, 5.0, 0.0), (21.0 + 1.0 * k, 6.0, 1.5))], 0) for k in range(5)]
    assert not any(footprints_after(moving))
    long_and_slow = [([surface((20.0 + 0.3 * k, 5.0, 0.0), (24.5 + 0.3 * k, 6.8, 1.5))], 0) for k in range(5)]
    assert not any(footprints_after(long_and_slow))
    # beside another cluster that holds none of its old cells
    beside = [
        (
            [
                surface((20.0 + 1.0 * k, 5.0, 0.0), (21.0 + 1.0 * k, 6.0, 1.5)),
                surface((20.0, 8.0, 0.0), (30.0, 9.0, 3.0), 1),
            ],
            0,
        )
        for k in range(5)
    ]
    assert not any(footprints_after(beside))
    # driving under a gantry: the beam above holds the cells over its old footprint, not the footprint
    gantry = surface((20.0, -5.0, 2.5), (22.0, 8.0, 3.5), 1)
    under = [([surface((18.0 + 0.6 * k, -1.0, 0.0), (19.8 + 0.6 * k, 1.0, 1.5)), gantry], 0) for k in range(6)]
    assert not any(footprints_after(under))


def object_leaving_a_standing_one(left_behind_frames: int) -> list[Obstacles]:
    """An object at 10 m/s; from frame 10 on another cluster stands where it was two frames before."""
    tracker = new_tracker(left_behind_frames=left_behind_frames)
    out = []
    for k in range(14):
        x = 20.0 + 1.0 * k
        pieces = [surface((x, 5.0, 0.0), (x + 1.0, 6.0, 1.5))]
        if k >= 10:
            pieces.append(surface((x - 2.0, 5.0, 0.0), (x - 1.0, 6.0, 1.5), cid=1, rgb=(0.1, 0.5, 0.7)))
        out.append(step(tracker, k, pieces))
    return out


def test_a_track_that_slid_off_a_standing_object_starts_again_from_rest() -> None:
    def first(o: Obstacles) -> Obstacle:
        return min(o.obstacles, key=lambda ob: ob.id)

    with_it, without = object_leaving_a_standing_one(2), object_leaving_a_standing_one(0)
    assert first(with_it[9]).moving and first(without[9]).moving
    assert first(with_it[9]).speed == pytest.approx(first(without[9]).speed)  # the same until then
    assert not first(with_it[10]).moving and first(with_it[10]).speed < 0.5
    assert first(without[10]).moving and first(without[10]).speed > 8.0


def test_an_oncoming_car_is_reported_at_its_speed_sooner_with_the_faces_line() -> None:
    # a car box coming at 9.6 m/s from 27 m: the filter starts it at rest and its prior holds the
    # first labelled frames back; the line through its last faces has no prior
    def errors(faces: int) -> tuple[list[float], list[float]]:
        tracker = new_tracker(velocity_faces=faces)
        moving, standing = [], []
        for k in range(14):
            x = 27.0 - 0.96 * k
            out = step(tracker, k, [counted(box_voxels((x, -3.0, 0.0), (x + 4.5, -1.25, 1.5))),
                                    counted(box_voxels((14.0, 4.0, 0.0), (14.5, 4.5, 1.5)))])  # fmt: skip
            for o in out.obstacles:
                if o.state == "tracked" and o.centroid[1] < 0.0 and o.moving:
                    moving.append(abs(float(np.linalg.norm(o.velocity[0:2])) - 9.6))
                if o.state == "tracked" and o.centroid[1] > 0.0:
                    standing.append(float(np.linalg.norm(o.velocity[0:2])))
        return moving, standing

    (blended, post_b), (alone, post_a) = errors(6), errors(0)
    assert len(blended) == len(alone) >= 5  # the label is the filter's either way
    assert sum(blended[:3]) < 0.8 * sum(alone[:3])  # the first labelled frames nearer its speed
    assert post_b == post_a  # a standing track reports the filter's velocity


def moving_tracks_of_two_walking(offset: tuple[float, float], sizes: tuple[tuple[float, float, float], ...],
                                 **overrides: object) -> list[list[tuple[int, float]]]:
    """Two clusters of different colours walking together at 1.5 m/s, ``offset`` (x, y) apart: each
    frame's moving tracked obstacles as (id, width in y)."""
    rng = np.random.default_rng(5)
    tracker = new_tracker(**overrides)
    frames = []
    for k in range(15):
        centre = np.array([12.0, -5.0, 0.9]) + np.array([1.5, 0.0, 0.0]) * k * 0.1
        jitter = rng.normal(scale=0.03, size=(2, 3))
        pieces = [cluster(0, centre + jitter[0], size=sizes[0], rgb=(0.7, 0.1, 0.1)),
                  cluster(1, centre + np.array([*offset, 0.0]) + jitter[1], size=sizes[1], rgb=(0.3, 0.6, 0.3))]
        out = step(tracker, k, pieces)
        frames.append([(o.id, round(float(o.bbox_max[1] - o.bbox_min[1]), 1)) for o in out.obstacles
                       if o.moving and o.state == "tracked"])
    return frames


def test_a_walker_and_a_piece_of_his_smear_are_one_moving_obstacle_two_walkers_are_two() -> None:
    walker, smear = (0.5, 0.5, 1.7), (1.6, 1.6, 1.5)
    twins: dict[str, object] = {}  # the shipped settings: 1.5 m wide, centres within 0.4 m, 0.75 m/s
    # without the rule both pieces become tracks and both are called moving: one is a false moving frame
    off = {"twin_overlap_m": -1.0, "twin_near_m": -1.0}
    assert max(len(f) for f in moving_tracks_of_two_walking((0.0, -0.5), (walker, smear), **off)) == 2
    # with it, only the narrow walker is, from the frame he turns moving on
    kept = moving_tracks_of_two_walking((0.0, -0.5), (walker, smear), **twins)
    assert any(kept) and all(len(f) <= 1 for f in kept)
    assert {w for f in kept for _, w in f} == {0.5}
    # two pieces of one width whose centres are 0.3 m apart are one walker and his smear too
    assert max(len(f) for f in moving_tracks_of_two_walking((0.0, -0.3), (walker, walker), **off)) == 2
    assert all(len(f) <= 1 for f in moving_tracks_of_two_walking((0.0, -0.3), (walker, walker), **twins))
    # two walking side by side, 0.7 m apart, are two
    both = moving_tracks_of_two_walking((0.0, -0.7), (walker, walker), **twins)
    assert max(len(f) for f in both) == 2 and both[-1] and len(both[-1]) == 2


def labels_of_an_oblique_smeared_walker(**overrides: object) -> list[bool]:
    """A walker 25 degrees right walking away along his line of sight at 1.5 m/s, smeared 2 m along it:
    his box is 2.2 m long and 1.3 m wide in y, his points half a metre across."""
    rng = np.random.default_rng(7)
    ray = np.array([np.cos(np.radians(-25.0)), np.sin(np.radians(-25.0))])
    tracker, labels = new_tracker(**overrides), []
    for k in range(14):
        start = 16.0 + 0.15 * k + rng.normal(scale=0.1)
        smear = [box_voxels((r * ray[0], r * ray[1], 0.0), (r * ray[0] + 0.4, r * ray[1] + 0.4, 1.75))
                 for r in np.arange(start, start + 2.0, 0.1)]
        (o,) = step(tracker, k, [counted(np.unique(np.vstack(smear), axis=0))]).obstacles
        labels.append(o.moving)
    return labels


def test_a_walker_smeared_along_an_oblique_line_of_sight_is_upright_by_his_points() -> None:
    by_box = labels_of_an_oblique_smeared_walker(upright_by_points_m=0.0)
    by_points = labels_of_an_oblique_smeared_walker(upright_by_points_m=1.5)
    # by his box he is no person (2.2 x 1.3 m) and his label flickers; by his points he is, and keeps it
    assert sum(by_points) > sum(by_box), (by_box, by_points)
    assert all(by_points[-4:]) and not any(by_box[-3:]), (by_box, by_points)
