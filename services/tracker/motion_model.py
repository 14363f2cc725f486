"""Moving or stationary, judged by gradient-boosted trees (``tracker.motion_model``).

The rule in labelling.py asks two lower bounds on a track's speed to clear a threshold, each
bound a speed less some of its doubt, with a refinement per kind of object (narrow, upright,
corners sure of a speed). Each refinement was measured on tracker replays, and by session 54 the
held-out walkers it still missed were followed at about their pace: a walker at 15-25 m walking
along the line of sight, smeared into a box 2-5 m long, whose bounds hover either side of the
threshold from frame to frame. Session 10's grid search over the two bounds found no threshold
that separates such walkers from the poles and bins whose smear swings alike.

Trees see every one of the rule's inputs at once (``FEATURES``: the filter's speed and doubt,
the faces' bounds, the slide, the motion across the line of sight, the corners, the box and the
points' shape, range and age) and learn where the moving tracks lie among them from synthetic
runs with ground truth: ``scripts/train_motion_model.py`` replays the tracker on them and asks
the evaluation's matching which tracks were on moving objects. A track turns moving when their
chance clears ``tracker.motion_model_on`` and stays moving while it clears
``motion_model_off`` (docs/results/tracking.md, "Session 55"). The corners followed on a track,
sure of a walker's pace, turn it moving too, as in the rule (``motion_model_corners``): the runs
the trees learnt from hold no walker going straight away down the lane. A track a frame younger
than the rule's ``moving_min_frames`` turns moving when their chance clears
``motion_model_young_on`` (0.97) and its filter knows its speed to ``motion_model_young_sigma_mps``:
a walker's track born late was often over 0.9 sure at its second frame, which the rule's age left
standing (docs/results/tracking.md, "Session 68").
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from common.boosted_trees import BoostedTrees
from services.tracker import motion_window
from services.tracker.fragments import Standing
from services.tracker.motion_state import across_sight, slide_speed, speed_and_sigma
from services.tracker.track import TrackTable

NDArray = npt.NDArray[Any]

#: the model trained on this repository's tuning runs (``tracker.motion_model = "builtin"``).
BUILTIN = Path(__file__).with_name("motion_model.json")

#: one row per track, in this order; a value unknown (no corners, no window) is NaN.
FEATURES: tuple[str, ...] = (
    "filter_speed", "filter_sigma", "box_slide",  # the filter's horizontal speed and doubt; the box's growth
    "near_bound", "far_bound",  # the faces' windows' speed bounds (motion_window.speed_bounds), near and far ends
    "across_speed", "across_sigma", "across_slide", "across_width",  # across the line of sight (motion_state)
    "across_bound",  # the faces' bound along that direction, the lower end's
    "corner_speed", "corner_sigma", "corner_count", "corner_across", "corner_across_sigma",  # keypoint_motion.py
    "extent_x", "extent_y", "extent_z", "extent_slow_x", "extent_slow_y",
    "points_across", "points_across_slow", "points_depth",  # the points' shape (anchor.py)
    "age", "floor", "range", "bearing", "upright", "nis", "faces",
    "radial_speed", "tangential_speed",  # the filter's velocity along and across the ray from the eye
    "hits",
)  # fmt: skip


class MotionModel(BoostedTrees):
    """The trees over ``FEATURES``: the chance that each track is on a moving object.

    ``tracker.motion_model``: "" for the rule (labelling.py), "builtin" for the bundled model, or a file.
    """

    FEATURES = FEATURES
    SETTING = "tracker.motion_model"
    SCRIPT = "scripts/train_motion_model.py"
    BUILTIN = BUILTIN


@dataclass(frozen=True)
class LearnedLabel:
    """The trees and their hysteresis (config ``tracker.motion_model``, ``motion_model_on``, ``motion_model_off``,
    ``motion_model_corners``, ``motion_model_young_on``, ``motion_model_young_sigma_mps``)."""

    model: MotionModel
    on: float  # a stationary track turns moving when the chance clears this
    off: float  # ... and a moving one stays moving while it clears this
    corners: bool = True  # corners sure of its pace also turn it moving, as in the rule (labelling.by_corners)
    young_on: float = 1.0  # a track a frame younger than the rule allows turns moving when the chance clears this
    young_sigma: float = float("inf")  # ... and its filter knows its speed to this (m/s, one sigma)


def learned_label(
    setting: str, on: float, off: float, corners: bool = True, young_on: float = 1.0, young_sigma: float = float("inf")
) -> LearnedLabel | None:
    """The configured trees with their hysteresis; None for the rule."""
    model = MotionModel.configured(setting)
    return None if model is None else LearnedLabel(model, on, off, corners, young_on, young_sigma)


def motion_features(
    t: TrackTable, voxel_edge: float, eye: NDArray, period_s: float, face_std: float, sigma_k: float,
    standing: Standing,
) -> NDArray:  # fmt: skip
    """(n, len(FEATURES)) rows of the tracks ``t`` seen from ``eye`` (world x, y); ``sigma_k`` is the
    faces' bounds' standard errors, as the rule takes them (``tracker.moving_sigma_k``)."""
    n = len(t)
    if n == 0:
        return np.zeros((0, len(FEATURES)))
    extent = t.bbox_max - t.bbox_min
    speed, sigma = speed_and_sigma(t.x[:, 3:6], t.p[:, 3:6, 3:6])
    slide = slide_speed(extent, t.extent_slow, period_s, voxel_edge)
    a = across_sight(t.x[:, 0:2], t.x[:, 3:5], t.p[:, 3:5, 3:5], extent, t.extent_slow, eye, period_s, voxel_edge)
    whole, along = motion_window.speed_bounds(
        np.concatenate([t.window, t.window_far]),
        np.concatenate([t.window_t, t.window_t]),
        np.concatenate([t.window_n, t.window_n]),
        face_std,
        sigma_k,
        np.concatenate([a.normal, a.normal]),
    )
    ray = t.x[:, 0:2] - eye
    distance = np.hypot(ray[:, 0], ray[:, 1])
    unit = ray / np.maximum(distance, 1e-9)[:, None]
    rows = np.empty((n, len(FEATURES)))  # filled column by column: a column_stack of 33 cost a tenth of the label
    rows[:, 0:3] = np.column_stack([speed, sigma, slide])
    rows[:, 3], rows[:, 4] = whole[:n], whole[n:]
    rows[:, 5], rows[:, 6], rows[:, 7], rows[:, 8] = a.speed, a.sigma, a.slide, a.width
    rows[:, 9] = np.minimum(along[:n], along[n:])
    rows[:, 10] = np.hypot(t.corner_velocity[:, 0], t.corner_velocity[:, 1])
    rows[:, 11], rows[:, 12], rows[:, 13], rows[:, 14] = (
        t.corner_sigma, t.corner_count, np.abs(t.corner_across), t.corner_across_sigma
    )
    rows[t.corner_count <= 0, 10:15] = (np.nan, np.nan, 0.0, np.nan, np.nan)  # no corners, no opinion
    rows[:, 15:18], rows[:, 18:20] = extent, t.extent_slow[:, 0:2]
    rows[:, 20], rows[:, 21], rows[:, 22] = t.across, t.across_slow, t.depth
    rows[:, 23], rows[:, 24], rows[:, 25] = t.age, t.floor, distance
    rows[:, 26] = np.abs(np.arctan2(unit[:, 1], unit[:, 0]))
    rows[:, 27], rows[:, 28], rows[:, 29] = standing.upright(extent), t.nis, t.window_n
    rows[:, 30] = np.abs((t.x[:, 3:5] * unit).sum(axis=1))
    rows[:, 31] = np.abs(t.x[:, 4] * unit[:, 0] - t.x[:, 3] * unit[:, 1])
    rows[:, 32] = t.hits
    rows[~np.isfinite(rows)] = np.nan  # -inf bounds (too few faces) and unknown widths alike: no opinion
    return rows
