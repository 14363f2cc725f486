"""Which linked parts are one object, judged by gradient-boosted trees (``voxel.join_model``).

The trees are trained by ``scripts/train_join_model.py`` on the flood fill's linked parts of
synthetic tuning runs, with the ground truth saying which pairs lie on one object, and walked by
common/boosted_trees.py.
"""

from __future__ import annotations

from pathlib import Path

from common.boosted_trees import BoostedTrees
from services.voxel_mapper.part_pairs import FEATURES

#: the model trained on this repository's tuning runs (``voxel.join_model = "builtin"``).
BUILTIN = Path(__file__).with_name("join_model.json")


class JoinModel(BoostedTrees):
    """The trees over ``part_pairs.FEATURES``: the chance that each pair of parts is one object.

    ``voxel.join_model``: "" for the share rule alone, "builtin" for the bundled model, or a file.
    """

    FEATURES = FEATURES
    SETTING = "voxel.join_model"
    SCRIPT = "scripts/train_join_model.py"
    BUILTIN = BUILTIN
