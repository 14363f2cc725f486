"""Gradient-boosted trees read from a JSON file and walked by a compiled kernel.

The stages learn two judgements from synthetic runs with ground truth: which linked parts are one
object (services/voxel_mapper/join_model.py) and which tracks move (services/tracker/motion_model.py).
Both are scikit-learn's ``HistGradientBoostingClassifier``, trained by a script in ``scripts/``
and exported as plain node arrays (``export``): a vehicle never unpickles code, and the services
need neither scikit-learn nor its version. ``tests/test_join_model.py`` checks the walk against
scikit-learn's own ``predict_proba``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

import numba
import numpy as np
import numpy.typing as npt

from common.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
NODE_KEYS = ("feature", "threshold", "left", "right", "leaf", "missing_left", "value", "roots")


@numba.njit(cache=True)
def _raw_scores(rows: F64, roots: I64, feature: I64, threshold: F64, left: I64, right: I64,
                leaf: npt.NDArray[np.bool_], missing_left: npt.NDArray[np.bool_], value: F64,
                baseline: float) -> F64:
    """Each row's summed leaf values over all trees (scikit-learn's raw prediction).

    Tree by tree, every row down each: one tree's nodes stay in the cache while the rows go down
    it. Row by row, all trees' nodes (a quarter of a megabyte for the tracker's 200 trees) went
    through the cache for each row, and the tracker's label took 0.3 ms a frame with 50 tracks.
    """
    out = np.full(rows.shape[0], baseline)
    for root in roots:
        for i in range(rows.shape[0]):
            k = root
            while not leaf[k]:
                x = rows[i, feature[k]]
                if np.isnan(x):
                    k = left[k] if missing_left[k] else right[k]
                elif x <= threshold[k]:
                    k = left[k]
                else:
                    k = right[k]
            out[i] += value[k]
    return out


@dataclass(frozen=True)
class BoostedTrees:
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

    #: what a kind of trees judges, set by each subclass: the rows' columns, the setting that
    #: chooses its file, the script that trains it again, and the model bundled with the code
    FEATURES: ClassVar[tuple[str, ...]] = ()
    SETTING: ClassVar[str] = ""
    SCRIPT: ClassVar[str] = ""
    BUILTIN: ClassVar[Path] = Path()

    @classmethod
    def configured(cls, setting: str) -> Self | None:
        """The setting's trees: "" for none, "builtin" for the bundled model, or a file."""
        if not setting:
            return None
        return cls.load(cls.BUILTIN if setting == "builtin" else setting)

    @classmethod
    def load(cls, path: str | Path) -> Self:
        """An exported model of ``FEATURES``, read as ``read`` reads one."""
        return cls.read(path, cls.FEATURES, cls.SETTING, cls.SCRIPT)

    @classmethod
    def read(cls, path: str | Path, features: tuple[str, ...], setting: str, script: str) -> Self:
        """An exported model for ``features``; a file that is not one, or was trained on other features,
        is named with the ``setting`` that chose it and the ``script`` that trains it again. (Session
        55's tracker calls this, and ``services.tracker.benchmark --against`` runs it on today's common/.)"""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
            names = tuple(data["features"])
            nodes = {key: np.asarray(data[key]) for key in NODE_KEYS}
            baseline = float(data["baseline"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{setting}: {path} is not a readable model of trees ({exc})") from exc
        if names != features:
            raise ConfigError(f"{setting}: {path} was trained on features {names}, this version computes "
                              f"{features}; train it again ({script})")
        size = len(nodes["feature"])
        if any(len(nodes[key]) != size for key in NODE_KEYS[1:-1]):
            raise ConfigError(f"{setting}: {path} has node arrays of different lengths")
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
        """Each row's chance of the positive answer."""
        if len(rows) == 0:
            return np.zeros(0)
        raw = _raw_scores(np.ascontiguousarray(rows, dtype=np.float64), self.roots, self.feature, self.threshold,
                          self.left, self.right, self.leaf, self.missing_left, self.value, self.baseline)
        return 1.0 / (1.0 + np.exp(-raw))


def export(model: Any, features: tuple[str, ...]) -> dict[str, Any]:
    """A fitted two-class ``HistGradientBoostingClassifier``'s trees as flat node arrays (``BoostedTrees``'s
    file). Only the fitted model's attributes are read: this module never imports scikit-learn."""
    out: dict[str, list[Any]] = {key: [] for key in NODE_KEYS}
    for (tree,) in model._predictors:  # one tree per iteration for two classes
        nodes, base = tree.nodes, len(out["feature"])
        out["roots"].append(base)
        out["feature"] += nodes["feature_idx"].tolist()
        out["threshold"] += nodes["num_threshold"].tolist()
        out["left"] += (nodes["left"].astype(np.int64) + base).tolist()
        out["right"] += (nodes["right"].astype(np.int64) + base).tolist()
        out["leaf"] += nodes["is_leaf"].astype(bool).tolist()
        out["missing_left"] += nodes["missing_go_to_left"].astype(bool).tolist()
        out["value"] += nodes["value"].tolist()
    return {"features": list(features), "baseline": float(np.ravel(model._baseline_prediction)[0]), **out}
