"""Moving or stationary, track by track, from two lower bounds on its speed.

The filter's bound is its speed less some of its own doubt (motion_state.label); the faces' bound
is the slope of the track's last faces less their scatter (motion_window.py). A track turns
moving only when both clear the threshold, so a velocity the filter learnt from a face that slid
is not believed until the faces move too; or when the corners the stereo stage follows on it are
sure it moves (``by_corners``, keypoint_motion.py, "Session 40"). Two corners or more, sure of a
speed (their median less two of their sigmas), may also stand in for the faces as the second
bound: a walker's faces at 15-25 m scatter with his smear while the corners on him do not
("Session 42"). Six refinements of the first
rule, each measured on tracker replays (docs/results/tracking.md):

- a narrow track (a walker, a cyclist, a pole) may be labelled by its motion across the line of
  sight, which stereo measures by bearing, not by its smeared range ("Session 17");
- an upright track's filter doubts its speed about twice as much as its faces scatter, so it
  needs fewer of those sigmas ("Session 20");
- a compact upright track is confirmed by its near face alone: its far end is the far fringe of
  its smear, which swings by metres from frame to frame ("Session 21");
- a narrow track's box growing along the line of sight does not count as slide: that growth is
  the smear's fringe, and the point followed is its points' middle range ("Session 35");
- narrow is judged by the track's points, not its box: a walker smeared along an oblique line of
  sight has an axis-aligned box metres wide across it, while his points are half a metre wide
  and their middle half lies within a metre along it; a wall seen edge-on is as thin across
  but deep all along, so it is not narrow ("Session 38");
- upright may be judged by the points too (``upright_by_points_m``, off): such a walker's box is no
  person's, 2-5 m by 1-2.5 m, so he needs twice the sigmas and both his faces; by his points he is
  a person sooner, but so are a bin and standing things KITTI 0001 has ("Session 54").

Since session 55 trees trained on tuning runs judge instead (``tracker.motion_model``,
motion_model.py): this rule labels a stream without followed corners, and every stream with
``tracker.motion_model=``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from services.tracker import motion_window
from services.tracker.fragments import Standing
from services.tracker.keypoint_motion import NO_CORNERS, CornerRule
from services.tracker.motion_model import FEATURES, LearnedLabel, motion_features
from services.tracker.motion_state import Hysteresis, across_sight, label, slide_speed, speed_and_sigma, width_slide
from services.tracker.track import TrackTable

NDArray = npt.NDArray[Any]

#: the column of the trees' rows that holds the filter's speed doubt
FILTER_SIGMA = FEATURES.index("filter_sigma")


@dataclass(frozen=True)
class MotionLabeller:
    """The label's rule and its settings (config: ``tracker.moving_*``, ``narrow_across_m``, ``upright_*``)."""

    hysteresis: Hysteresis
    standing: Standing  # what is upright: a person's or a pole's shape
    face_std: float  # a window's scatter is never taken below this (m)
    frame_period_s: float
    narrow_across_m: float = 0.0  # narrower across the line of sight: may be labelled by that motion; 0: off
    upright_sigma_k: float | None = None  # sigmas of doubt for an upright track; None: the hysteresis's
    near_only_m: float = 0.0  # an upright track at most this long (x and y) is confirmed by its near face
    narrow_by_points: bool = False  # narrow, and its slide, by its points across the line of sight, not its box
    corners: CornerRule = NO_CORNERS  # when the corners followed on a track label it
    upright_by_points_m: float = 0.0  # this tall, upright also when its points are upright_thin_m across; 0: off
    learned: LearnedLabel | None = None  # trees that judge instead of the rule (motion_model.py); None: the rule

    def label(self, t: TrackTable, voxel_edge: float, eye: NDArray, corners_seen: bool = True) -> NDArray:
        """The tracks' new moving flags; ``eye`` is the camera's world position (x, y).

        The trees, where configured, judge only a frame whose stream follows corners
        (``corners_seen``): they learnt from runs that did, and without any they read a walker at
        8 m at 0.87 at best (``tests/test_tracker.py``'s hand-built walkers), so the rule judges.
        """
        if self.learned is not None and corners_seen and self.corners.samples > 0:
            return self.by_model(t, voxel_edge, eye, self.learned)
        extent = t.bbox_max - t.bbox_min
        speed, sigma = speed_and_sigma(t.x[:, 3:6], t.p[:, 3:6, 3:6])
        slide = slide_speed(extent, t.extent_slow, self.frame_period_s, voxel_edge)
        k = self.hysteresis.sigma_k
        upright = self.standing.upright(extent)
        if self.upright_by_points_m > 0.0 and len(t):
            # a walker smeared along an oblique line of sight has a box wider than a person in x and
            # y, while his points are half a metre across and their core shallow (the narrow test's
            # depth); a wall seen edge-on is as thin across but deep all along
            with np.errstate(invalid="ignore"):
                thin = (np.maximum(t.across, t.across_slow) <= self.standing.thin_m) & (t.depth < self.narrow_across_m)
            upright |= thin & (extent[:, 2] >= self.upright_by_points_m) & (self.standing.thin_m > 0.0)
        if self.narrow_across_m > 0.0 and len(t):
            a = across_sight(
                t.x[:, 0:2], t.x[:, 3:5], t.p[:, 3:5, 3:5], extent, t.extent_slow, eye, self.frame_period_s, voxel_edge
            )
            confirm, across_confirm = self.window_bounds(t, k, upright, a.normal)
            narrow = a.width < self.narrow_across_m
            if self.narrow_by_points:
                # by its points (anchor.py): width across now and lately, and the core's depth along;
                # its slide is then its points' growth across, not its box's
                known = np.isfinite(t.across) & np.isfinite(t.across_slow)
                thin = (np.maximum(t.across, t.across_slow) < self.narrow_across_m) & (t.depth < self.narrow_across_m)
                narrow = np.where(known, thin, narrow)
                growth = width_slide(t.across, t.across_slow, self.frame_period_s, voxel_edge)
                a = dataclasses.replace(a, slide=np.where(known, growth, a.slide))
            # a narrow track is followed at its points' middle range (anchor.py), which the fringe
            # its box grows by along the line of sight hardly moves: only growth across it slides it
            slide = np.where(narrow, a.slide, slide)
            evidence = np.minimum(speed - k * sigma - slide, confirm)
            across_evidence = np.minimum(a.speed - k * a.sigma - a.slide, across_confirm)
            use = narrow & (across_evidence > evidence)
            speed, sigma, slide = (
                np.where(use, a.speed, speed),
                np.where(use, a.sigma, sigma),
                np.where(use, a.slide, slide),
            )
            confirm = np.where(use, across_confirm, confirm)
        else:
            confirm, _ = self.window_bounds(t, k, upright)
        if self.corners.confirm_count > 0 and self.corners.samples > 0:
            # the corners, sure of a speed, may be the second opinion the faces' window is
            low, _, _ = self._corner_speed(t)
            confirm = np.maximum(confirm, np.where(t.corner_count >= self.corners.confirm_count, low, -np.inf))
        upright_k = k if self.upright_sigma_k is None else self.upright_sigma_k
        sigma_k = np.where(upright, upright_k, k)
        moving = label(t.moving, speed, sigma, slide, t.age, self.hysteresis, confirm, sigma_k)
        if self.corners.samples > 0:
            moving = (moving & ~self.held_by_corners(t)) | self.by_corners(t)
        if self.hysteresis.max_floor_m > 0.0:
            # what moves on a road stands on it: a cluster held up in the air (a tree's crown, a sign)
            # does not turn moving, however its pieces swap from frame to frame
            moving &= t.moving | (t.floor <= self.hysteresis.max_floor_m)
        return moving

    def features(self, t: TrackTable, voxel_edge: float, eye: NDArray) -> NDArray:
        """The rows the trees judge (motion_model.FEATURES), as this rule's settings measure them."""
        return motion_features(
            t, voxel_edge, eye, self.frame_period_s, self.face_std, self.hysteresis.sigma_k, self.standing
        )

    def by_model(self, t: TrackTable, voxel_edge: float, eye: NDArray, learned: LearnedLabel) -> NDArray:
        """The trees' label, with a hysteresis of their chance; the track's age and floor gate it as the rule's."""
        rows = self.features(t, voxel_edge, eye)
        chance = learned.model.probability(rows)
        turn_on = (chance > learned.on) & (t.age >= self.hysteresis.min_frames)
        # a walker's track born late (his first lost or restarted) is two frames old when the rule's
        # age keeps it standing: on the held-out urban runs the trees were over 0.9 sure on 10 of
        # 16 such frames; over 0.97 they turned it moving a frame sooner with no false frame, and
        # where its filter knows its speed the label's speed is near the truth (a car's second
        # frame read 5.6 +- 3.4 of its 11 m/s)
        young = (chance > learned.young_on) & (t.age >= self.hysteresis.min_frames - 1)
        turn_on |= young & (rows[:, FILTER_SIGMA] <= learned.young_sigma)
        moving = np.where(t.moving, chance > learned.off, turn_on)
        if learned.corners:
            # corners sure of a walker's pace are physics the trees may not have seen: a walker going
            # straight away down the lane, 8 corners on him sure of 1.6 m/s, read under 0.5
            moving |= self.by_corners(t)
        if self.hysteresis.max_floor_m > 0.0:
            moving &= t.moving | (t.floor <= self.hysteresis.max_floor_m)
        return moving

    def _corner_speed(self, t: TrackTable) -> tuple[NDArray, NDArray, NDArray]:
        """The corners' median speed on each track less and plus ``sigma_k`` of their sigmas, and
        whether enough corners are on it for an opinion."""
        rule = self.corners
        speed = np.hypot(t.corner_velocity[:, 0], t.corner_velocity[:, 1])
        doubt = rule.sigma_k * t.corner_sigma
        low = speed - doubt
        if rule.across_std_m > 0.0:
            # across the line of sight a corner's place is known to millimetres, along it to
            # decimetres: its speed across is a lower bound on its speed, and a sure one
            with np.errstate(invalid="ignore"):
                low = np.maximum(low, np.abs(t.corner_across) - rule.sigma_k * t.corner_across_sigma)
        return low, speed + doubt, t.corner_count >= rule.min_count

    def held_by_corners(self, t: TrackTable) -> NDArray:
        """Which standing tracks the corners on them are sure stand still: none of them turns moving.

        A pole's cluster at 15-25 m swings along the line of sight with the smear around it, and its
        filter and faces can read a walker's pace for a few frames; the corners on it stay put.
        """
        if self.corners.still_mps <= 0.0:
            return np.zeros(len(t), dtype=bool)
        _, high, sure = self._corner_speed(t)
        return ~t.moving & sure & (high < self.corners.still_mps)

    def by_corners(self, t: TrackTable) -> NDArray:
        """Which tracks the corners on them call moving (keypoint_motion.py).

        Turning one on needs the corners sure (``sigma_k`` sigmas) of ``on_mps``, a little less than a walker's
        pace, and the filter's speed, doubt aside, over the threshold: corners on a pole's or a bin's
        edge see the background through their window and drift with it, while the filter sees the
        pole stand still. Keeping one moving needs them sure of the lower threshold alone. A group of
        them moving across the line of sight turns it moving too, however many more stand (``by_mover``).
        """
        low, _, sure = self._corner_speed(t)
        filtered = np.hypot(t.x[:, 3], t.x[:, 4])
        on = self.hysteresis.on
        turn_on = sure & (low > self.corners.on_mps) & (filtered > on) & (t.age >= self.hysteresis.min_frames)
        return np.where(t.moving, sure & (low >= self.hysteresis.off), turn_on) | self.by_mover(t, filtered)

    def by_mover(self, t: TrackTable, filtered: NDArray) -> NDArray:
        """Which tracks hold a group of corners moving across the line of sight (``CornerMover``),
        however many more stand, while the filter sees it move.

        A walker at 15-25 m on the pavement a voxel from a wall shares its cluster, and the wall's
        corners outvote his: 75 of urban's 111 walker-frames tracked but labelled standing (seeds
        7-100, session 70's runs) had a wall or a building within 1.5 m. His own corners read his
        motion across the line of sight to a few centimetres a second (docs/results/tracking.md,
        "Session 71").
        """
        m = self.corners.mover
        if m is None:
            return np.zeros(len(t), dtype=bool)
        count, speed, width = t.corner_mover[:, 0], t.corner_mover[:, 1], t.corner_mover[:, 2]
        group = (count >= m.count) & (np.abs(speed) >= m.mps) & (width <= m.width_m)
        return group & (filtered > m.filter_mps) & (t.age >= self.hysteresis.min_frames)

    def window_bounds(
        self, t: TrackTable, k: float, upright: NDArray, direction: NDArray | None = None
    ) -> tuple[NDArray, NDArray]:
        """The faces' bounds on the speed, whole and along ``direction``: the lower of both ends'.

        Both ends go through one fit, as they share times and counts; a compact upright track
        takes its near end's bound alone.
        """
        n = len(t)
        whole, along = motion_window.speed_bounds(
            np.concatenate([t.window, t.window_far]),
            np.concatenate([t.window_t, t.window_t]),
            np.concatenate([t.window_n, t.window_n]),
            self.face_std,
            k,
            None if direction is None else np.concatenate([direction, direction]),
        )
        extent = t.bbox_max - t.bbox_min
        near_only = upright & (extent[:, 0:2].max(axis=1) <= self.near_only_m)
        return (
            np.where(near_only, whole[:n], np.minimum(whole[:n], whole[n:])),
            np.where(near_only, along[:n], np.minimum(along[:n], along[n:])),
        )
