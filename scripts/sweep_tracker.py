"""Many tracker settings against many recorded runs, in one process: each run is read once.

``measure.py --from tracker`` restarts a run through the tracker and writes a new recording for
each setting, about four minutes for session 41's 61 runs. Here the runs' clusters, egomotion and
ground truth stay in memory and only the tracker and the evaluation's moving/speed tally run
again: about 13 s a setting over the same 61 runs. The figures are the ones ``evaluate`` gives
the restarted recording (tests/test_measure.py checks it), so a sweep picks candidates and
``measure.py`` confirms them.

    .venv/bin/python scripts/sweep_tracker.py --runs tuning=/tmp/m/s41T held=/tmp/m/s41 \\
        --set tracker.corner_samples=4 --variant base --variant on0.5 tracker.moving_on_mps=0.5

``--variants FILE`` reads one variant a line (a name, then its ``key=value`` settings; ``#``
comments). Each variant prints one line per set of runs: pooled moving TP / FP / FN frames and
speed RMSE, and the same per scenario.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from common.evaluation.evaluate import Evaluation, obstacle_figures  # noqa: E402
from common.evaluation.inputs import RunInputs, read_inputs  # noqa: E402
from common.messages import Clusters, EgoMotion  # noqa: E402
from common.recording import RecordingReader, open_recording  # noqa: E402
from services.pipeline import config_for  # noqa: E402
from services.tracker import Tracker  # noqa: E402


@dataclass
class LoadedRun:
    """What the tracker and the evaluation need of one run, read once."""

    name: str  # the scenario and seed, e.g. urban-s7
    reader: RecordingReader  # for the configuration the run was made with
    frames: list[tuple[int, Clusters, EgoMotion]]
    inputs: RunInputs


def load_run(path: Path) -> LoadedRun:
    reader = open_recording(path)
    seen: dict[int, dict[str, Any]] = {}
    for _, msg in reader.messages(topics=("voxel_mapper/clusters", "odometry/ego")):
        seen.setdefault(msg.frame_id, {})[type(msg).__name__] = msg
    frames = [(f, got["Clusters"], got["EgoMotion"]) for f, got in sorted(seen.items()) if len(got) == 2]
    inputs = read_inputs(path)
    inputs.clusters = {}  # segmentation is the mapper's figure: not scored again
    return LoadedRun(path.name.removesuffix("_run.mcap").removesuffix(".mcap"), reader, frames, inputs)


def score(run: LoadedRun, sets: list[str]) -> dict[str, Any]:
    """The run's moving and speed figures with the tracker remade under ``sets``."""
    tracker = Tracker.from_config(config_for(run.reader, None, sets, stored=True))
    run.inputs.obstacles = {f: tracker.process(clusters, ego) for f, clusters, ego in run.frames}
    figures = obstacle_figures(run.inputs, Evaluation(result={}))
    moving, speed = figures["moving"] or {}, figures["speed"] or {}
    return {
        "tp": int(moving.get("tp", 0)),
        "fp": int(moving.get("fp", 0)),
        "fn": int(moving.get("fn", 0)),
        "rmse_mps": speed.get("rmse_mps"),
        "pairs": int(speed.get("pairs", 0)),
    }


def pooled(rows: list[dict[str, Any]]) -> str:
    """TP / FP / FN summed, and the speed RMSE pooled by pairs."""
    tp, fp, fn = (sum(r[k] for r in rows) for k in ("tp", "fp", "fn"))
    pairs = sum(r["pairs"] for r in rows)
    sq = sum(r["pairs"] * r["rmse_mps"] ** 2 for r in rows if r["pairs"])
    return f"{tp}/{fp}/{fn}" + (f" {np.sqrt(sq / pairs):.2f}" if pairs else "")


def line(name: str, results: dict[str, dict[str, dict[str, Any]]]) -> str:
    parts = []
    for label, runs in results.items():
        scenarios: dict[str, list[dict[str, Any]]] = {}
        for run, row in runs.items():
            scenarios.setdefault(run.rsplit("-s", 1)[0], []).append(row)
        each = " ".join(f"{s} {pooled(r)}" for s, r in sorted(scenarios.items()))
        parts.append(f"{label} {pooled(list(runs.values()))} [{each}]")
    return f"{name:24s} " + " | ".join(parts)


def read_variants(args: argparse.Namespace) -> list[tuple[str, list[str]]]:
    variants = [(v[0], v[1:]) for v in args.variant or []]
    if args.variants:
        for text in Path(args.variants).read_text().splitlines():
            words = text.split("#", 1)[0].split()
            if words:
                variants.append((words[0], words[1:]))
    return variants or [("base", [])]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", nargs="+", required=True, metavar="LABEL=DIR", help="folders of *_run.mcap")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="under every variant")
    parser.add_argument("--variant", action="append", nargs="+", metavar="NAME [KEY=VALUE ...]")
    parser.add_argument("--variants", metavar="FILE", help="one variant a line: NAME KEY=VALUE ...")
    parser.add_argument("--json", type=Path, help="write every run's figures per variant here")
    args = parser.parse_args(argv)
    sets: dict[str, list[LoadedRun]] = {}
    start = time.monotonic()
    for spec in args.runs:
        label, _, folder = spec.rpartition("=")
        paths = sorted(Path(folder).glob("*_run.mcap"))
        if not paths:
            parser.error(f"{folder}: no *_run.mcap")
        sets[label or Path(folder).name] = [load_run(p) for p in paths]
    print(f"read {sum(map(len, sets.values()))} runs in {time.monotonic() - start:.0f} s", flush=True)
    out: dict[str, Any] = {}
    for name, extra in read_variants(args):
        start = time.monotonic()
        results = {label: {r.name: score(r, args.set + extra) for r in runs} for label, runs in sets.items()}
        print(f"{line(name, results)} ({time.monotonic() - start:.0f} s)", flush=True)
        out[name] = {"sets": extra, "runs": results}
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
