"""What the two tree-training scripts share: their command line, a pass over the runs for rows and
answers, the fit and the exported file (common/boosted_trees.py). Each script says how a run
becomes rows (``train_join_model.run_rows``, ``train_motion_model.run_rows``).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from common.boosted_trees import export
from common.progress import progress

Rows = tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]


def train(
    argv: list[str] | None, doc: str | None, again: str, run_rows: Callable[[Path, Sequence[str]], Rows],
    features: tuple[str, ...], trees: dict[str, Any], summary: str, rising: Sequence[str] = (),
) -> int:  # fmt: skip
    """Parse ``argv`` (runs, ``--out``, ``--set``), gather every run's rows, fit the trees (bound to
    rise with the ``rising`` features), write them to ``--out`` and print ``summary`` (formatted
    with ``rows`` and ``share``, the percentage answered 1): the exit code, 1 when the answers are
    all one (nothing to learn). ``again`` says what happens to a run's recorded stage while
    ``--set`` holds ("its clusters are tracked again")."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path, help="run recordings with ground truth (*_run.mcap)")
    parser.add_argument("--out", type=Path, required=True, help="the model file to write (JSON)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help=f"configuration over each run's own while {again}")  # fmt: skip
    args = parser.parse_args(argv)
    from sklearn.ensemble import HistGradientBoostingClassifier  # the dev extra: training only

    gathered = [run_rows(path, args.sets) for path in progress(args.runs, len(args.runs), "runs")]
    x, y = np.concatenate([r for r, _ in gathered]), np.concatenate([a for _, a in gathered])
    if len(np.unique(y)) < 2:
        print(f"{Path(sys.argv[0]).stem}: {len(y)} rows, all one answer; nothing to learn", file=sys.stderr)
        return 1
    bounds = {"monotonic_cst": [int(name in rising) for name in features]} if rising else {}
    model = HistGradientBoostingClassifier(**trees, **bounds).fit(x, y)
    args.out.write_text(json.dumps(export(model, features), separators=(",", ":")) + "\n")
    print(f"{summary.format(rows=len(y), share=100 * y.mean())}; {model.n_iter_} trees -> {args.out}")
    return 0
