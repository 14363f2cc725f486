"""How far segmentation would go with better stereo: the matcher's disparity handed, in whole or in
part, to the ground truth, and the rest of the pipeline as it is.

    .venv/bin/python scripts/stereo_ceiling.py --out /tmp/ceiling --jobs 2 /tmp/measure/urban-s7*.mcap

Each input recording (a synthetic scenario as ``scripts/measure.py`` renders it, with its
``groundtruth/disparity``) goes through ``stereovox process`` once per variant, with the stereo
stage's disparity map replaced as the variant says, and is scored by ``evaluate``:

- ``matcher``: the stereo stage as it ships;
- ``truth``: the true disparity;
- ``truth, low limits``: the same with the mapper's noise limits lowered (``LOW_LIMITS``): a thin
  pole or a far walker makes too few points for them without the matcher's fattening;
- ``truth + noise``: the true disparity plus independent Gaussian noise of ``NOISE_PX``, more than
  the matcher's own error away from depth steps (0.15-0.22 px RMS on urban, session 62);
- ``truth near steps`` / ``... wide``: the matcher's, except within 3 or 8 px
  of a true depth step, where it is the truth: what mending the matcher at steps alone would buy;
- ``dropped near steps``: the matcher's, with those pixels left out instead;
- ``truth where between`` / ``where flipped``: the truth near steps only where the matcher puts a
  pixel between the nearest and farthest true surface there, or on the wrong one (or beyond both);
- ``wrong dropped near steps``: near steps, the matcher's pixels over ``STEP_PX`` / 2 off the truth
  left out: a perfect detector of its errors there, without a cure;
- ``snapped near steps`` / ``..., square``: those pixels moved onto the nearer to the truth of the
  highest and lowest matcher disparity 4 columns to either side (or in the 9 x 9 square), where that
  one is right: a perfect choice between its own two plateaus, which is what a ramp filter
  (services/stereo_depth/ramps.py) can at best do;
- ``truth in holes``: the truth wherever the matcher gives no disparity;
- ``matcher, twice as wide``: no oracle, the matcher itself on the pair widened twice (``WIDE``);
- ``..., low limits``: as the variant, with the mapper's noise limits lowered (``LOW_LIMITS``).

Sessions 62 and 63's tables and figure (docs/results/voxel.md) came from here. The figure, ``ceiling.png``
in ``--out``, shows each variant's mean one-cluster, missed and merged shares.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from common.evaluation.evaluate import evaluate_recording  # noqa: E402
from common.recording import open_recording  # noqa: E402
from services.pipeline import process_file  # noqa: E402
from services.stereo_depth import core as stereo_core  # noqa: E402

F32 = npt.NDArray[np.float32]
#: a true depth step: two neighbours, along a row or a column, differ by more than this (px of disparity).
STEP_PX: float = 1.0
#: the noise of ``truth + noise`` (px, one sigma).
NOISE_PX: float = 0.25
#: the mapper's noise limits for exact points (defaults: 20 voxels, 8 points a voxel).
LOW_LIMITS: tuple[str, ...] = ("voxel.min_cluster_voxels=6", "voxel.min_points_per_voxel=2")
#: the matcher on the pair widened twice (``stereo.upsample_x``, services/stereo_depth/matcher.py).
WIDE: tuple[str, ...] = ("stereo.upsample_x=2",)


@dataclass(frozen=True)
class Variant:
    """Which disparity the stereo stage hands on, and the settings the rest runs with."""

    name: str
    source: str = "matcher"  # matcher | truth
    noise_px: float = 0.0  # Gaussian noise added to the truth
    # with the matcher, within ``reach_px`` of a true depth step: the truth ("truth"), nothing ("drop"), the
    # truth only where the matcher lies between the surfaces ("between") or on the wrong one ("flipped"), or
    # where it is wrong: nothing ("drop wrong") or the nearer of its own plateaus ("snap", "snap square")
    steps: str = ""
    reach_px: int = 3
    holes: bool = False  # with the matcher: the truth where it gives no disparity
    sets: tuple[str, ...] = field(default=())


VARIANTS: tuple[Variant, ...] = (
    Variant("matcher"),
    Variant("truth", source="truth"),
    Variant("truth, low limits", source="truth", sets=LOW_LIMITS),
    Variant("truth + noise", source="truth", noise_px=NOISE_PX),
    Variant("truth + noise, low limits", source="truth", noise_px=NOISE_PX, sets=LOW_LIMITS),
    Variant("truth near steps", steps="truth", reach_px=3),
    Variant("truth near steps, wide", steps="truth", reach_px=8),
    Variant("dropped near steps", steps="drop", reach_px=3),
    Variant("truth where between, near steps", steps="between", reach_px=3),
    Variant("truth where flipped, near steps", steps="flipped", reach_px=3),
    Variant("matcher, low limits", sets=LOW_LIMITS),
    Variant("matcher, twice as wide", sets=WIDE),
    Variant("matcher, twice as wide, low limits", sets=(*WIDE, *LOW_LIMITS)),
    Variant("truth near steps, low limits", steps="truth", reach_px=3, sets=LOW_LIMITS),
    Variant("wrong dropped near steps", steps="drop wrong", reach_px=3),
    Variant("wrong dropped near steps, low limits", steps="drop wrong", reach_px=3, sets=LOW_LIMITS),
    Variant("snapped near steps", steps="snap", reach_px=3),
    Variant("snapped near steps, low limits", steps="snap", reach_px=3, sets=LOW_LIMITS),
    Variant("snapped near steps, square", steps="snap square", reach_px=3),
    Variant("snapped near steps, square, low limits", steps="snap square", reach_px=3, sets=LOW_LIMITS),
    Variant("truth in holes", holes=True),
    Variant("truth in holes and near steps", steps="truth", reach_px=3, holes=True),
)


def near_steps(truth: F32, reach_px: int) -> npt.NDArray[np.bool_]:
    """Pixels within ``reach_px`` (along rows and columns) of a true depth step: two neighbours, along a
    row or a column, over ``STEP_PX`` apart. A slope is no step: the road's disparity changes by
    0.27 px a row on the synthetic rig, over 1 px across a window of seven rows."""
    known = np.nan_to_num(truth, nan=0.0)
    step = np.zeros(known.shape, dtype=bool)
    across = np.abs(np.diff(known, axis=1)) > STEP_PX
    step[:, :-1] |= across
    step[:, 1:] |= across
    down = np.abs(np.diff(known, axis=0)) > STEP_PX
    step[:-1, :] |= down
    step[1:, :] |= down
    return ndimage.maximum_filter(step, 2 * reach_px + 1)


def handed(variant: Variant, matcher: F32 | None, truth: F32, frame_id: int) -> F32:
    """The disparity the variant hands on for one frame (``matcher`` is needed unless it takes the truth)."""
    if variant.source == "truth":
        out = truth.astype(np.float32, copy=True)
        if variant.noise_px > 0.0:  # seeded by the frame: every variant and rerun sees the same noise
            out += np.random.default_rng(frame_id).normal(0.0, variant.noise_px, out.shape).astype(np.float32)
        return out
    assert matcher is not None
    out = matcher.astype(np.float32, copy=True)
    if variant.steps:
        near = near_steps(truth, variant.reach_px)
        if variant.steps in ("between", "flipped"):
            near &= wrong_near_steps(matcher, truth, variant.reach_px, between=variant.steps == "between")
        if variant.steps in ("drop wrong", "snap", "snap square"):
            with np.errstate(invalid="ignore"):
                near &= ~(np.abs(matcher - truth) <= 0.5 * STEP_PX)
        if variant.steps.startswith("snap"):
            out = snapped(out, truth, near, square=variant.steps == "snap square")
        else:
            out[near] = np.nan if variant.steps.startswith("drop") else truth[near]
    if variant.holes:
        hole = ~np.isfinite(out)
        out[hole] = truth[hole]
    return out


def snapped(out: F32, truth: F32, wrong: npt.NDArray[np.bool_], reach_px: int = 4, square: bool = False) -> F32:
    """``out`` with each ``wrong`` pixel moved onto the nearer to the truth of the highest and lowest
    matcher disparity within ``reach_px`` along its row (or in the square of that reach, ``square``):
    a perfect choice between the plateaus, made only where one of them is within ``STEP_PX`` / 2 of the truth."""
    size = (2 * reach_px + 1 if square else 1, 2 * reach_px + 1)
    lo = ndimage.minimum_filter(np.where(np.isfinite(out), out, np.inf), size)
    hi = ndimage.maximum_filter(np.where(np.isfinite(out), out, -np.inf), size)
    with np.errstate(invalid="ignore"):
        pick = np.where(np.abs(lo - truth) < np.abs(hi - truth), lo, hi)
    res = out.copy()
    with np.errstate(invalid="ignore"):
        ok = wrong & (np.abs(pick - truth) <= 0.5 * STEP_PX)  # where neither plateau is right, the pixel stays
    res[ok] = pick[ok]
    return res


def wrong_near_steps(matcher: F32, truth: F32, reach_px: int, between: bool) -> npt.NDArray[np.bool_]:
    """Pixels the matcher puts over ``STEP_PX`` / 2 off the truth: strictly between the nearest and the
    farthest true surface within the reach (``between``), or else (on the other surface, or beyond both)."""
    known = np.nan_to_num(truth, nan=0.0)
    size = 2 * reach_px + 1
    lo, hi = ndimage.minimum_filter(known, size), ndimage.maximum_filter(known, size)
    tol = 0.5 * STEP_PX
    with np.errstate(invalid="ignore"):
        wrong = np.abs(matcher - truth) > tol
        inside = (matcher > lo + tol) & (matcher < hi - tol)
    return wrong & (inside if between else ~inside)


def install(variant: Variant, truth: dict[int, F32]) -> Callable[[], None]:
    """Patch the stereo stage's disparity for this process; returns the undo."""
    original = stereo_core.StereoDepth._disparity

    def disparity(self: stereo_core.StereoDepth, frame: Any) -> F32:
        if frame.frame_id not in truth:
            raise ValueError(f"frame {frame.frame_id} has no true disparity (rendered with --disparity-every over 1?)")
        if variant.source == "matcher":
            return handed(variant, original(self, frame), truth[frame.frame_id], frame.frame_id)
        self._last_matcher, self.last_degenerate = None, False
        return handed(variant, None, truth[frame.frame_id], frame.frame_id)

    stereo_core.StereoDepth._disparity = disparity  # type: ignore[method-assign]

    def undo() -> None:
        stereo_core.StereoDepth._disparity = original  # type: ignore[method-assign]

    return undo


def read_truth(src: Path) -> dict[int, F32]:
    truth = {m.frame_id: np.asarray(m.disparity, dtype=np.float32) for _, m in open_recording(src).messages(
        topics=["groundtruth/disparity"])}  # fmt: skip
    if not truth:
        raise ValueError(f"{src}: no groundtruth/disparity (a synthetic scenario recording is needed)")
    return truth


def run_one(variant: Variant, src: Path, out: Path, max_frames: int | None = None) -> dict[str, Any]:
    """One input through the pipeline under the variant; the evaluation's JSON (also written beside the run)."""
    out.mkdir(parents=True, exist_ok=True)
    undo = install(variant, read_truth(src))
    try:
        run = out / f"{src.stem}_run.mcap"
        process_file(src, run, max_frames=max_frames, with_frames=False, sets=list(variant.sets))
    finally:
        undo()
    result = evaluate_recording(run)
    (out / f"{src.stem}.json").write_text(json.dumps(result))
    return result


SEGMENTATION: tuple[str, ...] = ("one_cluster_pct", "split_pct", "missed_pct", "merged_pct")


def summary(results: dict[str, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Per variant: segmentation shares (the mean of the runs', as the README's), moving frames summed."""
    rows = []
    for name, runs in results.items():
        seg = [r["segmentation"] for r in runs if r.get("segmentation")]
        moving = [r["moving"] for r in runs if r.get("moving")]
        rows.append({
            "variant": name, "runs": len(runs),
            **{k: float(np.mean([s[k] for s in seg])) for k in SEGMENTATION},
            **{k: int(sum(m[k] for m in moving)) for k in ("tp", "fp", "fn")},
        })  # fmt: skip
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    lines = ["| variant | one cluster % | split % | missed % | merged % | moving TP / FP / FN frames |",
             "| --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for r in rows:
        lines.append(f"| {r['variant']} | {r['one_cluster_pct']:.1f} | {r['split_pct']:.1f} | {r['missed_pct']:.1f} | "
                     f"{r['merged_pct']:.1f} | {r['tp']} / {r['fp']} / {r['fn']} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r["variant"] for r in rows]
    y = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(8, 0.5 * len(rows) + 1.5))
    for k, (key, colour) in enumerate((("one_cluster_pct", "tab:green"), ("missed_pct", "tab:red"),
                                       ("merged_pct", "tab:orange"))):  # fmt: skip
        ax.barh(y + (k - 1) * 0.27, [r[key] for r in rows], height=0.27, color=colour, label=key.removesuffix("_pct"))
    ax.axvline(90.0, color="grey", linestyle="--", linewidth=1)
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.set_xlabel("% of counted object-frames (merged: % of clusters)")
    ax.set_title("urban segmentation, the stereo stage's\ndisparity handed in part to the truth")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.6 / (0.5 * len(rows) + 1.5)), ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def slug(variant: Variant) -> str:
    """The variant's folder name: ``truth + noise, low limits`` -> ``truth_plus_noise_low_limits``."""
    return variant.name.replace(", ", "_").replace(" + ", "_plus_").replace(" ", "_")


def _job(args: tuple[Variant, Path, Path, int | None]) -> tuple[str, dict[str, Any]]:
    variant, src, out, max_frames = args
    return variant.name, run_one(variant, src, out, max_frames)


def summarise(out: Path) -> int:
    """The table and figure of every variant whose folder in ``out`` holds runs' JSON, in ``VARIANTS``' order:
    variants run at different times (or their folders linked into one) shown together."""
    results = {v.name: [json.loads(p.read_text()) for p in sorted((out / slug(v)).glob("*.json"))] for v in VARIANTS}
    results = {name: runs for name, runs in results.items() if runs}
    if not results:
        print(f"{out}: no variant's JSON", file=sys.stderr)
        return 1
    rows = summary(results)
    (out / "summary.md").write_text(markdown(rows))
    (out / "summary.json").write_text(json.dumps(rows, indent=1))
    plot(rows, out / "ceiling.png")
    print(markdown(rows))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="*", type=Path, help="scenario recordings with groundtruth/disparity")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--only", default="", help="comma-separated variants, as named in folders (default: all)")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--max-frames", type=int)
    parser.add_argument("--summarise", action="store_true",
                        help="run nothing: the table and figure of the variants' JSON already in --out")  # fmt: skip
    args = parser.parse_args(argv)
    if args.summarise:
        return summarise(args.out)
    wanted = set(args.only.split(",")) if args.only else {slug(v) for v in VARIANTS}
    chosen = [v for v in VARIANTS if slug(v) in wanted]
    if unknown := wanted - {slug(v) for v in VARIANTS}:
        parser.error(f"no variant {sorted(unknown)}; there are {[slug(v) for v in VARIANTS]}")
    if not args.inputs:
        parser.error("no inputs (only --summarise runs without)")
    args.out.mkdir(parents=True, exist_ok=True)
    jobs = [(v, src, args.out / slug(v), args.max_frames) for v in chosen for src in args.inputs]
    results: dict[str, list[dict[str, Any]]] = {v.name: [] for v in chosen}
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for done, (name, result) in enumerate(pool.map(_job, jobs), start=1):
            results[name].append(result)
            one = result["segmentation"]["one_cluster_pct"]
            print(f"{done}/{len(jobs)} {name}: one cluster {one:.1f} %", flush=True)
    rows = summary(results)
    table = markdown(rows)
    (args.out / "summary.md").write_text(table)
    (args.out / "summary.json").write_text(json.dumps(rows, indent=1))
    plot(rows, args.out / "ceiling.png")
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
