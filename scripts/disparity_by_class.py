"""The matcher's disparity error on each class of object, against the simulator's truth.

    .venv/bin/python scripts/disparity_by_class.py --seeds 7,8 [--set stereo.KEY=VALUE ...]

Renders a synthetic scenario's frames (no recording needed), runs the stereo core on them and
compares the disparity it publishes (the matcher's, before the reprojection moves ramp pixels:
ramps.py) with the renderer's, pixel by pixel, on the objects whose median depth lies
in a band (15-29 m by default: where issue 7's clusters merge and drift off their objects). Per
class, and per band of pixels by their distance along the row to another surface (the silhouette's
first and second column, and the rest), it prints the share of pixels with no estimate, the share
more than ``OFF_PX`` off and the share that far *behind* the truth, and, per object-frame, the
median signed error and its absolute value. A cluster's centroid goes where most of its pixels
put it, so the per-object median is what moves a pole's cluster off the pole; the pixel shares are
what strings it to the surface behind (docs/results/stereo.md, "Session 59").
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.config_loading import load_config
from common.messages import StereoFrame
from common.scenarios.render import Renderer, Rig
from common.scenarios.simulate import FRAME_RATE_HZ, scenario_world
from services.stereo_depth.core import StereoDepth

#: a pixel this far from the truth (px) is off: 0.8 m of range at 25 m on the synthetic rig.
OFF_PX = 0.3
#: columns from the silhouette reported on their own; the rest are the object's inside.
EDGE_COLUMNS = 2
#: an object-frame needs this many pixels with a true disparity to be counted.
MIN_PIXELS = 20
BANDS = ("column 1", "column 2", "inside")


def row_distance(ids: npt.NDArray[np.int32], reach: int = EDGE_COLUMNS + 1) -> npt.NDArray[np.int32]:
    """Columns from each pixel to the nearest pixel of another surface along its row, capped at ``reach``.

    Along the row only: the smear of a depth step runs along the rows (the baseline's direction).
    The image's own left and right borders are no surface and do not count.
    """
    dist = np.full(ids.shape, reach, np.int32)
    for step in range(reach - 1, 0, -1):
        other = np.zeros(ids.shape, bool)
        other[:, step:] |= ids[:, step:] != ids[:, :-step]
        other[:, :-step] |= ids[:, :-step] != ids[:, step:]
        dist[other] = step
    return dist


@dataclass
class ClassTally:
    """One class's pixels per band and its object-frames' median errors."""

    pixels: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    invalid: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    off: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    behind: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    medians: list[float] = field(default_factory=list)

    def add(self, error: npt.NDArray[np.float32], band_of: npt.NDArray[np.int32]) -> None:
        """One object-frame: ``error`` (estimate minus truth, NaN where no estimate) and each pixel's band index."""
        for k, band in enumerate(BANDS):
            e = error[band_of == k]
            self.pixels[band] += len(e)
            self.invalid[band] += int(np.isnan(e).sum())
            self.off[band] += int((np.abs(e) > OFF_PX).sum())  # NaN compares False
            self.behind[band] += int((e < -OFF_PX).sum())
        if np.isfinite(error).any():
            self.medians.append(float(np.nanmedian(error)))


def tally_frame(
    tallies: dict[str, ClassTally],
    estimate: npt.NDArray[np.float32],
    truth: npt.NDArray[np.float32],
    depth: npt.NDArray[np.float32],
    ids: npt.NDArray[np.int32],
    classes: dict[int, str],
    depth_band: tuple[float, float],
) -> None:
    """Add one frame's objects whose median true depth lies in ``depth_band`` (m) to their class's tally."""
    band_of = row_distance(ids) - 1  # 0, 1: the silhouette's columns; 2: inside
    error = estimate - truth
    for oid in np.unique(ids[ids >= 0]):
        mask = (ids == oid) & np.isfinite(truth)
        if mask.sum() < MIN_PIXELS or not depth_band[0] <= float(np.median(depth[mask])) <= depth_band[1]:
            continue
        tallies[classes.get(int(oid), "other")].add(error[mask], band_of[mask])


def report(tallies: dict[str, ClassTally]) -> list[str]:
    """A table: per class its object-frames' median errors, then per band its pixels' shares."""
    lines = [
        f"{'class':11s} {'objects':>7s} {'median px':>9s} {'|median|':>8s}  {'band':8s} {'pixels':>7s} "
        f"{'none':>5s} {'off':>5s} {'behind':>6s}   (off, behind: more than {OFF_PX} px)"
    ]
    for name, t in sorted(tallies.items()):
        m = np.asarray(t.medians)
        head = f"{name:11s} {len(m):7d} {np.median(m):+9.3f} {np.median(np.abs(m)):8.3f}" if len(m) else f"{name:11s}"
        for band in BANDS:
            seen = max(t.pixels[band] - t.invalid[band], 1)
            lines.append(
                f"{head:38s}  {band:8s} {t.pixels[band]:7d} {t.invalid[band] / max(t.pixels[band], 1):5.2f} "
                f"{t.off[band] / seen:5.2f} {t.behind[band] / seen:6.2f}"
            )
            head = ""
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="urban")
    parser.add_argument("--seeds", default="7,8", help="comma-separated scenario seeds")
    parser.add_argument("--frames", type=int, default=60, help="frames rendered per seed")
    parser.add_argument("--every", type=int, default=4, help="measure every Nth of them")
    parser.add_argument("--near", type=float, default=15.0, help="nearest median depth of an object counted (m)")
    parser.add_argument("--far", type=float, default=29.0, help="farthest (m)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="configuration override")
    args = parser.parse_args(argv)
    stereo = StereoDepth.from_config(load_config(None, args.set))
    tallies: dict[str, ClassTally] = defaultdict(ClassTally)
    for seed in (int(s) for s in args.seeds.split(",")):
        world = scenario_world(args.scenario, seed)
        renderer = Renderer(world, Rig())
        classes = {thing.id: thing.cls for thing in world.things}
        for k in range(0, args.frames, args.every):
            shot = renderer.render(k / FRAME_RATE_HZ, np.random.default_rng([seed, k]))
            frame = StereoFrame(frame_id=k, stamp_ns=k, left=shot.left, right=shot.right, calib=renderer.calib)
            _, disparity = stereo.process(frame)
            tally_frame(
                tallies,
                disparity.disparity,
                shot.disparity,
                shot.depth,
                shot.object_ids,
                classes,
                (args.near, args.far),
            )
            print(f"\rseed {seed} frame {k + 1}/{args.frames}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    print("\n".join(report(tallies)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
