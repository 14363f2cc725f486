"""The learned moving label: its file, what it calls moving in a hand-built street, and its training."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import load_script
from test_tracker import EDGE, box_voxels, counted, new_tracker, of_voxels, step

from common.errors import ConfigError
from common.evaluation.evaluate import evaluate_recording
from common.messages import Clusters, EgoMotion
from services.demo import BUNDLED
from services.pipeline import process_file
from services.tracker.motion_model import BUILTIN, FEATURES, LearnedLabel, MotionModel
from services.voxel_mapper.join_model import BUILTIN as JOIN_MODEL

train = load_script("train_motion_model")


def test_a_model_file_that_is_not_one_or_of_other_features_is_named(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match=r"tracker\.motion_model: .*bad\.json is not a readable model"):
        MotionModel.load(bad)
    with pytest.raises(ConfigError, match=r"join_model\.json was trained on features .*train_motion_model\.py"):
        MotionModel.load(JOIN_MODEL)  # the mapper's trees judge pairs of parts, not tracks
    with pytest.raises(ConfigError, match=r"tracker\.motion_model: .*missing\.json"):
        new_tracker(motion_model=str(tmp_path / "missing.json"))
    assert MotionModel.configured("") is None
    assert isinstance(MotionModel.configured("builtin"), MotionModel)
    assert json.loads(BUILTIN.read_text())["features"] == list(FEATURES)


def street(motion_model: str, seed: int, corners: bool = True, frames: int = 20) -> list[dict[str, bool]]:
    """A walker 16 m ahead walking away along the pavement at 1.4 m/s and a pole 21 m ahead, each
    cluster smeared 1-3.5 m behind it (a new length every frame), 10 and 8 corners on them with
    0.15 m of range noise; the moving label of each, frame by frame."""
    rng = np.random.default_rng(seed)
    tracker = new_tracker(motion_model=motion_model)
    on_walker = rng.uniform([-0.15, -0.2, 0.2], [0.15, 0.2, 1.6], (10, 3))
    on_pole = rng.uniform([-0.1, -0.1, 0.3], [0.1, 0.1, 2.8], (8, 3))
    labels = []
    for k in range(frames):
        w, p = np.array([16.0 + 0.14 * k, -4.0, 0.0]), np.array([21.0, 3.0, 0.0])
        smear_w, smear_p = rng.uniform(1.0, 3.5, 2)
        walker = of_voxels(box_voxels((w[0] - 0.5, w[1] - 0.25, 0.0), (w[0] + smear_w, w[1] + 0.25, 1.75)), 0)
        pole = of_voxels(box_voxels((p[0] - 0.5, p[1] - 0.125, 0.0), (p[0] + smear_p, p[1] + 0.125, 3.0)), 1)
        seen = np.vstack([w + on_walker, p + on_pole])
        seen[:, 0] += rng.normal(0.0, 0.15, len(seen))
        ids = np.arange(len(seen) if corners else 0)
        clusters = Clusters(frame_id=k, stamp_ns=k * 100_000_000, clusters=[walker, pole], voxel_edge=EDGE,
                            keypoint_ids=ids, keypoints=seen[ids], keypoint_std=np.full(len(ids), 0.15, np.float32))
        found = tracker.process(clusters, EgoMotion(frame_id=k, stamp_ns=k * 100_000_000, valid=True)).obstacles
        labels.append({("walker" if o.centroid[1] < 0 else "pole"): o.moving for o in found})
    return labels


def test_the_trees_call_a_smeared_walker_moving_and_a_pole_smeared_alike_standing() -> None:
    for seed in (1, 2):
        labels = street("builtin", seed)
        walker = [frame["walker"] for frame in labels]
        assert any(walker[:8]), (seed, walker)  # within 0.8 s
        assert all(walker[walker.index(True):]), (seed, walker)  # and kept
        assert not any(frame["pole"] for frame in labels), seed


def test_a_stream_without_followed_corners_is_labelled_by_the_rule() -> None:
    # the trees learnt from runs whose corners were followed: without any they read this walker at
    # under 0.9, so the rule judges such a stream, and the trees' setting changes nothing
    assert street("builtin", 2, corners=False) == street("", 2, corners=False)
    assert street("builtin", 2) != street("", 2)  # with corners the trees judge (here the rule calls him sooner)


@pytest.mark.timeout(600)
def test_training_rows_are_the_tracked_tracks_the_evaluation_matched(tmp_path: Path) -> None:
    run = tmp_path / "urban-s7_run.mcap"
    assert process_file(BUNDLED, run, max_frames=16, with_frames=False) == 16
    x, y = train.run_rows(run, ["tracker.motion_model="])
    assert x.shape == (len(y), len(FEATURES)) and set(y.tolist()) == {0, 1}
    moving = evaluate_recording(run)["moving"]
    # every tracked obstacle the evaluation scored as on a moving object (after its warm-up) is a row
    # on one; tracks on standing objects and on nothing are rows too
    assert int(y.sum()) >= moving["tp"] > 0 and int((y == 0).sum()) > 0
    model = tmp_path / "model.json"
    assert train.main([str(run), "--out", str(model), "--set", "tracker.motion_model="]) == 0
    chance = MotionModel.load(model).probability(x)
    assert np.mean((chance > 0.5) == (y == 1)) > 0.8  # it learnt its own rows


def test_corners_sure_of_his_pace_call_a_walker_going_straight_away_moving_where_the_trees_doubt() -> None:
    # the trees' runs hold no walker going straight away down the lane: his motion is all along the
    # line of sight, where theirs always had some across it, and they read him under 0.5 throughout
    from test_tracker_corners import _noisy_walk

    for seed in (0, 1):
        trees_alone = _noisy_walk(True, 1.6, seed, motion_model_corners=False)
        with_corners = _noisy_walk(True, 1.6, seed)
        assert not any(trees_alone), seed
        assert any(with_corners[:6]) and all(with_corners[-5:]), (seed, with_corners)
        assert not any(_noisy_walk(True, 0.0, seed))  # a post whose cluster swings as much


class _Sure:
    """Trees that give every track the same chance."""

    def __init__(self, chance: float) -> None:
        self.chance = chance

    def probability(self, rows: np.ndarray) -> np.ndarray:
        return np.full(len(rows), self.chance)


def test_a_track_a_frame_younger_than_the_rule_allows_turns_moving_only_when_the_trees_are_surer() -> None:
    tracker = new_tracker()
    for k in range(3):
        step(tracker, k, [counted(box_voxels((15.0 + 0.15 * k, -4.0, 0.0), (15.5 + 0.15 * k, -3.5, 1.75)))])
    t, labeller = tracker.tracks, tracker.labeller
    assert len(t) == 1 and labeller.hysteresis.min_frames == 3
    assert labeller.learned is not None and labeller.learned.young_on == 0.97  # the default

    assert labeller.learned.young_sigma == 1.0

    def moving(chance: float, age: int, young_on: float = 0.97, speed_sigma: float = 0.5) -> bool:
        t.age[:], t.moving[:], t.floor[:] = age, False, 0.0
        t.p[:, 3:6, 3:6] = np.eye(3) * speed_sigma**2
        learned = LearnedLabel(_Sure(chance), 0.9, 0.5, False, young_on, 1.0)  # type: ignore[arg-type]
        return bool(labeller.by_model(t, EDGE, np.zeros(2), learned)[0])

    assert moving(0.92, 3) and not moving(0.92, 2)  # sure enough at three frames old, not at two
    assert moving(0.98, 2) and not moving(0.96, 2)  # at two, only surer
    assert not moving(0.99, 2, speed_sigma=2.0)  # ... and only if its filter knows its speed
    assert moving(0.92, 3, speed_sigma=2.0)  # which the trees judge alone from three frames on
    assert not moving(0.99, 1)  # never at one
    assert not moving(0.99, 2, young_on=1.0)  # 1: as before
