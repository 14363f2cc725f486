"""Many tracker (or mapper) settings against many recorded runs, in one process: each run is read once.

``measure.py --from tracker`` restarts a run through the tracker and writes a new recording for
each setting, about four minutes for session 41's 61 runs. Here the runs' clusters, egomotion and
ground truth stay in memory and only the tracker and the evaluation's moving/speed tally run
again: about 13 s a setting over the same 61 runs. The figures are the ones ``evaluate`` gives
the restarted recording (tests/test_measure.py checks it), so a sweep picks candidates and
``measure.py`` confirms them.

    .venv/bin/python scripts/sweep_tracker.py --runs tuning=/tmp/m/s41T held=/tmp/m/s41 \\
        --set tracker.corner_samples=4 --variant base --variant on0.5 tracker.moving_on_mps=0.5

``--from voxel_mapper`` keeps the point clouds instead and remakes the clusters too, for the
mapper's settings: 28 s a setting over 52 runs of urban, crossing, overtake and slope with
``--jobs 2`` (about 2 MB of points a frame held in memory), and the mean one-cluster share is
printed beside each scenario's counts.

``--variants FILE`` reads one variant a line (a name, then its ``key=value`` settings; ``#``
comments). Each variant prints one line per set of runs: pooled moving TP / FP / FN frames and
speed RMSE, stationary recall, obstacle precision and the per-track figures (``pooled``), and the
same per scenario.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from common.evaluation.evaluate import Evaluation, obstacle_figures  # noqa: E402
from common.evaluation.inputs import RunInputs, cluster_boxes, read_inputs  # noqa: E402
from common.messages import Clusters, EgoMotion, PointCloud  # noqa: E402
from common.recording import RecordingReader, open_recording  # noqa: E402
from services.pipeline import RESUMABLE, config_for  # noqa: E402
from services.tracker import Tracker  # noqa: E402
from services.voxel_mapper import VoxelMapper  # noqa: E402


@dataclass
class LoadedRun:
    """What the tracker and the evaluation need of one run, read once."""

    name: str  # the scenario and seed, e.g. urban-s7
    reader: RecordingReader  # for the configuration the run was made with
    frames: list[tuple[int, Clusters | PointCloud, EgoMotion]]  # the stage's inputs (RESUMABLE)
    inputs: RunInputs


def scenario(run: str) -> str:
    """A run's scenario: SCENARIO-sSEED for a synthetic run, its whole name for a real one (kitti-tracking-0001)."""
    return run.rsplit("-s", 1)[0]


def load_run(path: Path, stage: str = "tracker") -> LoadedRun:
    reader = open_recording(path)
    seen: dict[int, list[Any]] = {}
    for _, msg in reader.messages(topics=RESUMABLE[stage]):
        got = seen.setdefault(msg.frame_id, [None, None])
        got[isinstance(msg, EgoMotion)] = msg
    frames = [(f, got[0], got[1]) for f, got in sorted(seen.items()) if None not in got]
    inputs = read_inputs(path)
    inputs.clusters = {}  # segmentation is the mapper's figure: scored only when the mapper runs again
    return LoadedRun(path.name.removesuffix("_run.mcap").removesuffix(".mcap"), reader, frames, inputs)


def score(run: LoadedRun, sets: list[str]) -> dict[str, Any]:
    """The run's moving and speed figures with the tracker (and the mapper, if the run holds points) remade."""
    cfg = config_for(run.reader, None, sets, stored=True)
    tracker = Tracker.from_config(cfg)
    mapper = VoxelMapper.from_config(cfg) if run.frames and isinstance(run.frames[0][1], PointCloud) else None
    run.inputs.obstacles = {}
    for f, given, ego in run.frames:
        clusters = mapper.process(given, ego) if mapper is not None else given
        assert isinstance(clusters, Clusters)
        if mapper is not None:
            run.inputs.clusters[f] = cluster_boxes(clusters)
        run.inputs.obstacles[f] = tracker.process(clusters, ego)
    ev = Evaluation(result={})
    figures = obstacle_figures(run.inputs, ev)
    moving, speed, segments = figures["moving"] or {}, figures["speed"] or {}, figures["segmentation"] or {}
    counts = ev.tally  # what stationary recall and precision are pooled from
    return {
        "tp": int(moving.get("tp", 0)),
        "fp": int(moving.get("fp", 0)),
        "fn": int(moving.get("fn", 0)),
        "rmse_mps": speed.get("rmse_mps"),
        "pairs": int(speed.get("pairs", 0)),
        "one_cluster_pct": segments.get("one_cluster_pct"),
        "stationary": counts.stationary,
        "stationary_matched": counts.stationary_matched,
        "stationary_moving": counts.stationary_moving,
        "matched": counts.matched,
        "phantoms": counts.phantoms,
        "all_moving_tracks": (figures["moving_tracks"] or {}).get("recall") == 1.0,
        "false_moving_tracks": int((figures["stationary_tracks"] or {}).get("false_moving", 0)),
    }


#: the runs a forked worker scores (set before the pool forks, so they are not copied per task)
_RUNS: list[LoadedRun] = []


def _score_one(task: tuple[int, list[str]]) -> dict[str, Any]:
    return score(_RUNS[task[0]], task[1])


def pooled(rows: list[dict[str, Any]]) -> str:
    """TP / FP / FN summed, the speed RMSE pooled by pairs, and the mean one-cluster % where scored;
    then stationary recall / labelled moving (%) and obstacle precision from the summed counts, the
    runs whose every moving track was labelled moving, and the stationary tracks called moving (fm)."""
    tp, fp, fn = (sum(r[k] for r in rows) for k in ("tp", "fp", "fn"))
    pairs = sum(r["pairs"] for r in rows)
    sq = sum(r["pairs"] * r["rmse_mps"] ** 2 for r in rows if r["pairs"])
    one = [r["one_cluster_pct"] for r in rows if r.get("one_cluster_pct") is not None]
    rmse = f" {np.sqrt(sq / pairs):.3f}" if pairs else ""
    out = f"{tp}/{fp}/{fn}{rmse}" + (f" one {np.mean(one):.1f}" if one else "")
    keys = ("stationary", "stationary_matched", "stationary_moving", "matched", "phantoms")
    standing, found, called, matched, phantoms = (sum(r[k] for r in rows) for k in keys)
    if standing:
        out += f" still {100 * found / standing:.1f}/{100 * called / max(found, 1):.1f}"
    if matched + phantoms:
        out += f" prec {matched / (matched + phantoms):.3f}"
    full = sum(r["all_moving_tracks"] for r in rows)
    return out + f" all {full}/{len(rows)} fm {sum(r['false_moving_tracks'] for r in rows)}"


def line(name: str, results: dict[str, dict[str, dict[str, Any]]]) -> str:
    parts = []
    for label, runs in results.items():
        scenarios: dict[str, list[dict[str, Any]]] = {}
        for run, row in runs.items():
            scenarios.setdefault(scenario(run), []).append(row)
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
    parser.add_argument("--from", dest="stage", choices=tuple(RESUMABLE)[::-1], default="tracker")
    parser.add_argument("--only", help="scenarios to read, comma-separated (e.g. urban,crossing)")
    parser.add_argument("--jobs", type=int, default=1, help="runs scored at once, in forked workers")
    args = parser.parse_args(argv)
    only = set(args.only.split(",")) if args.only else None
    labels: list[str] = []
    _RUNS.clear()
    start = time.monotonic()
    for spec in args.runs:
        label, _, folder = spec.rpartition("=")
        paths = sorted(Path(folder).glob("*_run.mcap"))
        paths = [p for p in paths if only is None or scenario(p.name.removesuffix("_run.mcap")) in only]
        if not paths:
            parser.error(f"{folder}: no *_run.mcap" + (f" of {args.only}" if only else ""))
        for path in paths:
            _RUNS.append(load_run(path, args.stage))
            labels.append(label or Path(folder).name)
    print(f"read {len(_RUNS)} runs in {time.monotonic() - start:.0f} s", flush=True)
    pool = multiprocessing.get_context("fork").Pool(args.jobs) if args.jobs > 1 else None
    out: dict[str, Any] = {}
    try:
        for name, extra in read_variants(args):
            start = time.monotonic()
            tasks = [(i, args.set + extra) for i in range(len(_RUNS))]
            rows = pool.map(_score_one, tasks) if pool is not None else [_score_one(t) for t in tasks]
            results: dict[str, dict[str, dict[str, Any]]] = {}
            for label, run, row in zip(labels, _RUNS, rows, strict=True):
                results.setdefault(label, {})[run.name] = row
            print(f"{line(name, results)} ({time.monotonic() - start:.0f} s)", flush=True)
            out[name] = {"sets": extra, "runs": results}
    finally:
        if pool is not None:
            pool.terminate()
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
