"""Which linked parts are one object, judged by gradient-boosted trees (``voxel.join_model``).

The trees are scikit-learn's ``HistGradientBoostingClassifier``, trained by
``scripts/train_join_model.py`` on the flood fill's linked parts of synthetic tuning runs, with
the ground truth saying which pairs lie on one object. They are exported as plain node arrays
(JSON, no pickle: a vehicle never unpickles code) and walked here by a compiled kernel, so the
service needs neither scikit-learn nor its version; ``tests/test_join_model.py`` checks the walk
against scikit-learn's own ``predict_proba``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np
import numpy.typing as npt

from common.errors import ConfigError
from services.voxel_mapper.part_pairs import FEATURES

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: the model trained on this repository's tuning runs (``voxel.join_model = "builtin"``).
BUILTIN = Path(__file__).with_name("join_model.json")


@numba.njit(cache=True)
def _raw_scores(rows: F64, roots: I64, feature: I64, threshold: F64, left: I64, right: I64,
                leaf: npt.NDArray[np.bool_], missing_left: npt.NDArray[np.bool_], value: F64,
                baseline: float) -> F64:
    """Each row's summed leaf values over all trees (scikit-learn's raw prediction)."""
    out = np.empty(rows.shape[0])
    for i in range(rows.shape[0]):
        total = baseline
        for root in roots:
            k = root
            while not leaf[k]:
                x = rows[i, feature[k]]
                if np.isnan(x):
                    k = left[k] if missing_left[k] else right[k]
                elif x <= threshold[k]:
                    k = left[k]
                else:
                    k = right[k]
            total += value[k]
        out[i] = total
    return out


@dataclass(frozen=True)
class JoinModel:
    """Trees as flat node arrays: children are absolute node indices, ``roots`` each tree's first node."""

    baseline: float
    roots: I64
    feature: I64
    threshold: F64
    left: I64
    right: I64
    leaf: npt.NDArray[np.bool_]
    missing_left: npt.NDArray[np.bool_]
    value: F64

    @classmethod
    def load(cls, path: str | Path) -> JoinModel:
        """Read an exported model; a file that is not one, or was trained on other features, is named."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
            names = tuple(data["features"])
            nodes = {key: np.asarray(data[key]) for key in ("feature", "threshold", "left", "right", "leaf",
                                                            "missing_left", "value", "roots")}
            baseline = float(data["baseline"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"voxel.join_model: {path} is not a readable join model ({exc})") from exc
        if names != FEATURES:
            raise ConfigError(f"voxel.join_model: {path} was trained on features {names}, this version computes "
                              f"{FEATURES}; train it again (scripts/train_join_model.py)")
        size = len(nodes["feature"])
        if any(len(nodes[key]) != size for key in ("threshold", "left", "right", "leaf", "missing_left", "value")):
            raise ConfigError(f"voxel.join_model: {path} has node arrays of different lengths")
        return cls(
            baseline=baseline,
            roots=nodes["roots"].astype(np.int64),
            feature=nodes["feature"].astype(np.int64),
            threshold=nodes["threshold"].astype(np.float64),
            left=nodes["left"].astype(np.int64),
            right=nodes["right"].astype(np.int64),
            leaf=nodes["leaf"].astype(np.bool_),
            missing_left=nodes["missing_left"].astype(np.bool_),
            value=nodes["value"].astype(np.float64),
        )

    def probability(self, rows: F64) -> F64:
        """The chance that each pair of parts is one object."""
        if len(rows) == 0:
            return np.zeros(0)
        raw = _raw_scores(np.ascontiguousarray(rows, dtype=np.float64), self.roots, self.feature, self.threshold,
                          self.left, self.right, self.leaf, self.missing_left, self.value, self.baseline)
        return 1.0 / (1.0 + np.exp(-raw))


def load_join_model(setting: str) -> JoinModel | None:
    """``voxel.join_model``: "" for the share rule alone, "builtin" for the bundled model, or a file."""
    if not setting:
        return None
    return JoinModel.load(BUILTIN if setting == "builtin" else setting)
