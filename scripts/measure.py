"""Every accuracy figure the README quotes, measured in one go: scenarios and real data through
``process`` and ``evaluate``, written as JSON and as the README's markdown tables.

    .venv/bin/python scripts/measure.py --out /tmp/measure            # everything (~10 min)
    .venv/bin/python scripts/measure.py --out /tmp/measure --only urban,kitti-tracking

Scenarios are rendered with seeds 7 and 8 by default, which no parameter was tuned on (tuning
uses seeds 1-6). ``--seeds 7,8,9,10`` widens the held-out set; the pooled table then sums each
scenario's counts over its seeds, since one 40-frame run holds only 5-10 moving objects and two
seeds differ by more than most changes do. Real data comes from ../shared/data (KITTI raw 0009,
tracking 0001, odometry 04, Middlebury cones and teddy).

A change to the mapper or the tracker alone is measured in seconds per run by restarting the runs
of an earlier measurement at that stage (``stereovox process --from``) instead of running stereo
and odometry again; ``--set`` applies to either kind of run::

    .venv/bin/python scripts/measure.py --out /tmp/base --seeds 1,2,3,4,5,6 --only urban,crossing
    .venv/bin/python scripts/measure.py --out /tmp/k1 --seeds 1,2,3,4,5,6 --only urban,crossing \\
        --from tracker --runs /tmp/base --set tracker.moving_sigma_k=1.0
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from common.datasets import kitti_odometry, kitti_raw, kitti_tracking, middlebury  # noqa: E402
from common.evaluation.evaluate import evaluate_recording  # noqa: E402
from common.scenarios.simulate import simulate_to_file  # noqa: E402
from services.pipeline import RESUMABLE, process_file  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
SCENARIOS = ("urban", "crossing", "overtake", "hanging", "slope", "lowtexture")
RAW = SHARED / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0009_sync"
ODO = SHARED / "kitti_odometry" / "dataset"

REAL: dict[str, Callable[[Path], Any]] = {
    "kitti-raw-0009": lambda out: kitti_raw.import_drive(RAW, out, max_frames=51),
    "kitti-tracking-0001": lambda out: kitti_tracking.import_sequence(
        SHARED / "kitti_tracking" / "training", "0001", out, max_frames=51
    ),
    "kitti-odometry-04": lambda out: kitti_odometry.import_sequence(
        ODO / "sequences" / "04", ODO / "poses" / "04.txt", out, max_frames=40
    ),
    "middlebury": lambda out: middlebury.import_scenes(SHARED / "middlebury", out),
}


def measure(
    name: str,
    make: Callable[[Path], Any],
    folder: Path,
    sets: list[str] | None = None,
    restart: tuple[str, Path] | None = None,
) -> dict[str, Any] | None:
    """Run (or, with ``restart`` = (stage, runs folder), restart that folder's run) and evaluate it.

    None when the run to restart is not in the folder.
    """
    source, run = folder / f"{name}.mcap", folder / f"{name}_run.mcap"
    started = time.perf_counter()
    if restart is not None:
        stage, runs = restart
        earlier = runs / f"{name}_run.mcap"
        if not earlier.exists():
            print(f"{name}: no {earlier} to restart, left out", file=sys.stderr)
            return None
        process_file(earlier, run, with_frames=False, sets=sets, resume_from=stage)
    else:
        if not source.exists():
            make(source)
        process_file(source, run, with_frames=False, sets=sets)
    result = evaluate_recording(run)
    (folder / f"{name}.json").write_text(json.dumps(result, indent=1))
    print(f"{name}: {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    return result


def pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def fraction(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def get(result: dict[str, Any], *path: str) -> Any:
    for key in path:
        if not isinstance(result, dict) or result.get(key) is None:
            return None
        result = result[key]
    return result


def tracking_table(results: dict[str, dict[str, Any]]) -> str:
    rows = [
        "| run | moving TP / FP / FN % | moving tracks recall (latency, frames) | speed RMSE m/s "
        "| stationary recall % / labelled moving % | parked tracks called moving | obstacle precision "
        "| id switches | one-cluster % | phantom clusters / frame |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, r in results.items():
        if not any(r.get(k) for k in ("moving", "stationary_tracks", "segmentation")):
            continue
        moving = r.get("moving") or {}
        tracks = r.get("moving_tracks") or {}
        latency = tracks.get("median_latency_frames")
        stationary = r.get("stationary") or {}
        rows.append(
            f"| {name} | {pct(moving.get('tp_pct'))} / {pct(moving.get('fp_pct'))} / {pct(moving.get('fn_pct'))} "
            f"| {fraction(tracks.get('recall'))} ({'-' if latency is None else f'{latency:.0f}'}) "
            f"| {fraction(get(r, 'speed', 'rmse_mps'))} "
            f"| {pct(None if stationary.get('recall') is None else 100 * stationary['recall'])} / "
            f"{pct(stationary.get('mislabelled_moving_pct'))} "
            f"| {get(r, 'stationary_tracks', 'false_moving')} of {get(r, 'stationary_tracks', 'tracks')} "
            f"| {fraction(get(r, 'obstacles', 'precision'))} | {r.get('id_switches')} "
            f"| {pct(get(r, 'segmentation', 'one_cluster_pct'))} "
            f"| {pct(get(r, 'segmentation', 'phantom_clusters_per_frame'))} |"
        )
    return "\n".join(rows)


def pooled_table(results: dict[str, dict[str, Any]]) -> str:
    """Per scenario, moving counts summed over its seeds and speed RMSE pooled over their TP pairs."""
    rows = [
        "| scenario | runs | moving TP / FP / FN % | speed RMSE m/s | parked tracks called moving |",
        "| --- | --- | --- | --- | --- |",
    ]
    groups: dict[str, list[dict[str, Any]]] = {}
    for name, r in results.items():
        scenario, _, seed = name.rpartition("-s")
        if scenario in SCENARIOS and seed.isdigit() and r.get("moving"):
            groups.setdefault(scenario, []).append(r)
    for scenario, runs in groups.items():
        tp, fp, fn = (sum(r["moving"][k] for r in runs) for k in ("tp", "fp", "fn"))
        speed = [(get(r, "speed", "rmse_mps") or 0.0, get(r, "speed", "pairs") or 0) for r in runs]
        pairs = sum(n for _, n in speed)
        squared = sum(rmse**2 * n for rmse, n in speed)
        parked = sum(get(r, "stationary_tracks", "false_moving") or 0 for r in runs)
        tracks = sum(get(r, "stationary_tracks", "tracks") or 0 for r in runs)
        total = max(tp + fp + fn, 1)
        rows.append(
            f"| {scenario} | {len(runs)} | {100 * tp / total:.1f} / {100 * fp / total:.1f} / {100 * fn / total:.1f} "
            f"| {fraction((squared / pairs) ** 0.5 if pairs else None)} | {parked} of {tracks} |"
        )
    return "\n".join(rows)


def geometry_table(results: dict[str, dict[str, Any]]) -> str:
    rows = [
        "| run | odometry t_err % | r_err deg/m | final drift % | stereo D1-all % | D1-est % | density % |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, r in results.items():
        if not (r.get("odometry") or r.get("stereo")):
            continue
        odo, st = r.get("odometry") or {}, r.get("stereo") or {}
        r_err = odo.get("r_err_deg_per_m")
        rows.append(
            f"| {name} | {pct(odo.get('t_err_pct'))} | {'-' if r_err is None else f'{r_err:.4f}'} "
            f"| {pct(odo.get('final_drift_pct'))} | {pct(st.get('d1_all_pct'))} | {pct(st.get('d1_est_pct'))} "
            f"| {pct(st.get('density_pct'))} |"
        )
    return "\n".join(rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="working folder (recordings, JSON, tables)")
    parser.add_argument("--only", default="", help="comma-separated subset: scenario names and/or real data names")
    parser.add_argument("--frames", type=int, default=40, help="frames per scenario")
    parser.add_argument("--seeds", default="7,8", help="comma-separated scenario seeds (1-6 were tuned on)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--from", dest="restart_from", choices=list(RESUMABLE), help="restart --runs' runs here")
    parser.add_argument("--runs", type=Path, help="folder of an earlier measurement whose runs --from restarts")
    args = parser.parse_args()
    if (args.restart_from is None) != (args.runs is None):
        parser.error("--from and --runs go together")
    if args.runs is not None and args.runs.resolve() == args.out.resolve():
        parser.error("--runs must be another folder than --out: the restarted runs would overwrite their inputs")
    restart = None if args.runs is None else (args.restart_from, args.runs)
    seeds = [int(s) for s in args.seeds.split(",") if s]
    args.out.mkdir(parents=True, exist_ok=True)
    only = {s for s in args.only.split(",") if s}
    jobs: dict[str, Callable[[Path], Any]] = {}
    for scenario in SCENARIOS:
        for seed in seeds:
            jobs[f"{scenario}-s{seed}"] = lambda out, sc=scenario, sd=seed: simulate_to_file(sc, out, args.frames, sd)
    jobs.update(REAL)
    measured = {
        name: measure(name, make, args.out, args.sets, restart)
        for name, make in jobs.items()
        if not only or any(name.startswith(o) for o in only)
    }
    results = {name: r for name, r in measured.items() if r is not None}
    tables = (
        f"### Obstacles\n\n{tracking_table(results)}\n\n### Obstacles, each scenario's seeds pooled\n\n"
        f"{pooled_table(results)}\n\n### Odometry and stereo\n\n{geometry_table(results)}\n"
    )
    (args.out / "tables.md").write_text(tables)
    print(tables)
    return 0


if __name__ == "__main__":
    sys.exit(main())
