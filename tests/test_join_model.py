"""The learned linkage: its exported trees, its rows, and what it joins in a hand-built scene."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import load_script
from sklearn.ensemble import HistGradientBoostingClassifier

from common.errors import ConfigError
from services.voxel_mapper.join_model import BUILTIN, JoinModel
from services.voxel_mapper.part_pairs import FEATURES
from tests.test_voxel_mapper import BLUE, GLASS, GREY, RED, box, cloud, ego, mapper, road

train = load_script("train_join_model")


def test_the_exported_trees_give_scikit_learns_probabilities(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    x = rng.normal(size=(3000, len(FEATURES)))
    y = (x[:, 2] + 0.5 * x[:, 6] ** 2 - x[:, 16] + rng.normal(0, 0.3, 3000)) > 0.4
    x[rng.random(x.shape) < 0.01] = np.nan  # missing values take the side the trees learnt for them
    model = HistGradientBoostingClassifier(max_iter=40, max_depth=4, random_state=0).fit(x, y)
    path = tmp_path / "model.json"
    path.write_text(json.dumps(train.export(model)))
    ours = JoinModel.load(path).probability(x[:500])
    assert ours == pytest.approx(model.predict_proba(x[:500])[:, 1], abs=1e-9)
    assert 0.05 < float(np.mean(ours > 0.5)) < 0.95  # a model that says something


def test_a_model_file_that_is_not_one_or_of_other_features_is_named(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match=r"voxel\.join_model: .*bad\.json is not a readable model"):
        JoinModel.load(bad)
    other = json.loads(BUILTIN.read_text())
    other["features"] = other["features"][:-1]
    moved = tmp_path / "other.json"
    moved.write_text(json.dumps(other))
    with pytest.raises(ConfigError, match=r"other\.json was trained on features"):
        JoinModel.load(moved)
    assert JoinModel.configured("") is None
    assert isinstance(JoinModel.configured("builtin"), JoinModel)


def test_each_voxel_belongs_to_the_nearest_box_within_reach() -> None:
    boxes = [(np.array([10.0, 0.0, 1.0]), np.array([4.0, 2.0, 2.0]), 0.0),  # a car
             (np.array([10.0, 2.0, 0.9]), np.array([0.3, 0.5, 1.8]), 0.0)]  # a walker beside it
    points = np.array([[10.0, 0.0, 1.0],  # in the car
                       [10.0, 1.9, 1.0],  # in the walker (and 0.9 m from the car's side)
                       [10.0, 2.6, 1.0],  # 0.35 m beyond the walker's far side
                       [10.0, 6.0, 1.0]])  # 3.75 m from both: nobody's
    assert train.owners(points, boxes).tolist() == [0, 1, 1, -1]
    # a part is the object most of its voxels are nearest; one of voxels near nothing is nobody's
    parts = np.array([0, 1, 1, 2], dtype=np.int32)
    assert train.part_owners(points, parts, 3, boxes).tolist() == [0, 1, -1]


@pytest.mark.parametrize(
    ("scene", "objects"),
    [
        ("car of paint and glass", 1),
        ("boot and rear window 0.7 m behind it", 1),
        ("walker in coat and trousers", 1),
        ("walker 0.1 m before a facade", 2),
        ("walker beside a pole", 2),
    ],
)
def test_the_builtin_model_keeps_objects_whole_and_neighbours_apart_as_the_rule_does(scene: str, objects: int) -> None:
    coat, legs = box((12.05, -0.2, 1.0), (12.3, 0.2, 1.7), RED), box((12.05, -0.2, 0.3), (12.3, 0.2, 0.95), BLUE)
    parts = {
        "car of paint and glass": [box((6, -0.9, 0.25), (10.3, 0.9, 0.9), RED),
                                   box((7.0, -0.8, 0.95), (9.4, 0.8, 1.45), GLASS)],
        "boot and rear window 0.7 m behind it": [box((20.0, -0.9, 0.3), (20.05, 0.9, 0.95), RED),
                                                 box((20.7, -0.8, 0.95), (20.75, 0.8, 1.45), GLASS)],
        "walker in coat and trousers": [coat, legs],
        "walker 0.1 m before a facade": [coat, legs, box((11.0, 0.3, 0.0), (16.0, 0.6, 3.2), GREY)],
        "walker beside a pole": [coat, legs, box((12.1, 0.3, 0.0), (12.26, 0.46, 3.0), GREY)],
    }[scene]
    model_alone = mapper(join_model="builtin", join_probability=0.5, join_veto=1.01)  # every rule join judged too
    assert len(model_alone.process(cloud(road(), *parts), ego()).clusters) == objects
    assert len(mapper(join_model="").process(cloud(road(), *parts), ego()).clusters) == objects  # as the rule does


def constant_model(chance: float) -> JoinModel:
    """Trees that give every pair the same chance: one leaf, the rest in the baseline."""
    leaf = np.ones(1, dtype=bool)
    return JoinModel(baseline=float(np.log(chance / (1.0 - chance))), roots=np.zeros(1, dtype=np.int64),
                     feature=np.zeros(1, dtype=np.int64), threshold=np.zeros(1), left=np.zeros(1, dtype=np.int64),
                     right=np.zeros(1, dtype=np.int64), leaf=leaf, missing_left=leaf, value=np.zeros(1))


def test_the_rule_decides_where_the_model_is_unsure_and_gives_way_where_it_is_sure() -> None:
    body, cabin = box((6, -0.9, 0.25), (10.3, 0.9, 0.9), RED), box((7.0, -0.8, 0.95), (9.4, 0.8, 1.45), GLASS)
    red, blue = box((6, -1, 0), (7.95, 1, 1.5), RED), box((8, -1, 0), (10, 1, 1.5), BLUE)

    def clusters(parts: list, chance: float | None) -> int:
        m = mapper()  # the rule's join stands from 0.5, and any pair over 0.8 is joined
        m.join_model = None if chance is None else constant_model(chance)
        return len(m.process(cloud(road(), *parts), ego()).clusters)

    assert clusters([body, cabin], None) == 1 and clusters([red, blue], None) == 2  # the share rule alone
    assert clusters([body, cabin], 0.6) == 1 and clusters([red, blue], 0.6) == 2  # unsure: as the rule has it
    assert clusters([body, cabin], 0.3) > 1  # doubted: the rule's joins are undone
    assert clusters([red, blue], 0.9) == 1  # sure: joined, though the rule leaves them apart
