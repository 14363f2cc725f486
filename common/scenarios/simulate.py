"""``stereovox simulate``: render a named scenario into a recording with its exact ground truth.

Per frame (10 Hz) the recording holds a StereoFrame on ``camera/stereo`` and, on
``groundtruth/*``, the ego pose, every object near the ego, and the left image's dense
disparity (optionally only every n-th frame, to keep a bundled recording small). The info
metadata says ``gt_complete``: every above-ground structure is an object.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.config import Config, VolumeConfig
from common.errors import ConfigError
from common.messages import (
    GroundTruthDisparity,
    GroundTruthEgo,
    GroundTruthObject,
    GroundTruthObjects,
    StereoFrame,
    key_for,
)
from common.progress import progress
from common.recording import RecordingWriter
from common.scenarios.catalogue import SCENARIOS, build
from common.scenarios.render import Rendered, Renderer, Rig
from common.scenarios.world import Look, World
from common.wire_arrays import IMAGE_FORMATS

log = logging.getLogger(__name__)

FRAME_RATE_HZ = 10.0
#: capture time of frame 0 (ns): a fixed epoch keeps recordings reproducible byte for byte.
EPOCH_NS = 1_700_000_000_000_000_000
FRAME_NS = 100_000_000
#: objects farther than this from the ego (m) are left out of a frame's ground truth.
TRUTH_RADIUS = 80.0


@dataclass
class FrameMessages:
    """Everything one frame contributes to a recording."""

    stereo: StereoFrame
    ego: GroundTruthEgo
    objects: GroundTruthObjects
    disparity: GroundTruthDisparity | None
    render_s: float


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"size {text!r} is not WIDTHxHEIGHT, e.g. 640x480") from None
    if not (64 <= w <= 4096 and 48 <= h <= 4096):
        raise ConfigError(f"size {w}x{h} outside 64x48 .. 4096x4096")
    return w, h


def truth_objects(rendered: Rendered, frame: int, stamp: int) -> GroundTruthObjects:
    ego_xy = rendered.ego_pose[:2, 3]
    objects = []
    for st in rendered.states:
        if np.linalg.norm(st.pose[:2, 3] - ego_xy) > TRUTH_RADIUS:
            continue
        oid = st.thing.id
        objects.append(GroundTruthObject(
            id=oid, cls=st.thing.cls, center=st.center, size=np.asarray(st.thing.size, float), yaw=st.yaw,
            velocity=st.velocity, moving=st.moving, visible_pixels=rendered.visible_pixels.get(oid, 0),
            visible_fraction=float(rendered.visible_fraction.get(oid, 0.0)),
        ))
    return GroundTruthObjects(frame_id=frame, stamp_ns=stamp, objects=objects, gt_complete=True)


def scenario_world(scenario: str, seed: int, dusk: bool = False, look: dict[str, float] | None = None) -> World:
    """The scenario's world, with the dusk look and any camera look fields (``noise_sigma``, ...) replaced."""
    world = build(scenario, seed, dusk)
    if look:
        unknown = set(look) - {f.name for f in dataclasses.fields(Look)}
        if unknown:
            raise ConfigError(f"unknown look fields {sorted(unknown)}")
        world = dataclasses.replace(world, look=dataclasses.replace(world.look, **look))
    return world


def frame_messages(scenario: str, frames: int, seed: int, size: tuple[int, int] = (640, 480),
                   image_format: str = "png", dusk: bool = False, disparity_every: int = 1,
                   look: dict[str, float] | None = None) -> Iterator[FrameMessages]:
    """Render a scenario frame by frame; the generator tests and other tools consume."""
    if image_format not in IMAGE_FORMATS:
        raise ConfigError(f"image format {image_format!r} unknown; choose from {', '.join(IMAGE_FORMATS)}")
    world = scenario_world(scenario, seed, dusk, look)
    renderer = Renderer(world, Rig(width=size[0], height=size[1]))
    calib = renderer.calib
    for k in range(frames):
        start = time.perf_counter()
        rendered = renderer.render(k / FRAME_RATE_HZ, np.random.default_rng([seed, k]))
        stamp = EPOCH_NS + k * FRAME_NS
        stereo = StereoFrame(frame_id=k, stamp_ns=stamp, left=rendered.left, right=rendered.right,
                             calib=calib, image_format=image_format)
        ego = GroundTruthEgo(frame_id=k, stamp_ns=stamp, pose=rendered.ego_pose,
                             velocity=world.ego_velocity(k / FRAME_RATE_HZ))
        disparity = None
        if disparity_every > 0 and k % disparity_every == 0:
            disparity = GroundTruthDisparity(frame_id=k, stamp_ns=stamp, disparity=rendered.disparity)
        yield FrameMessages(stereo, ego, truth_objects(rendered, k, stamp), disparity, time.perf_counter() - start)


def recording_info(scenario: str, seed: int, frames: int, size: tuple[int, int], disparity_every: int,
                   look: Look) -> dict[str, Any]:
    calib = Rig(width=size[0], height=size[1]).calibration()
    return {
        "source": "synthetic", "scenario": scenario, "seed": seed, "gt_complete": True,
        "frame_rate_hz": FRAME_RATE_HZ, "frames": frames, "volume": dataclasses.asdict(VolumeConfig()),
        "calib": {"fx": calib.fx, "fy": calib.fy, "cx": calib.cx, "cy": calib.cy, "baseline": calib.baseline,
                  "width": calib.width, "height": calib.height, "cam_to_vehicle": calib.cam_to_vehicle.tolist()},
        "disparity_every": disparity_every, "look": dataclasses.asdict(look),
    }


def simulate_to_file(scenario: str, out: Path, frames: int, seed: int, size: tuple[int, int] = (640, 480),
                     image_format: str = "png", dusk: bool = False, disparity_every: int = 1,
                     look: dict[str, float] | None = None) -> Path:
    """Render ``frames`` frames of a scenario into ``out`` (written atomically); returns ``out``."""
    if frames < 1:
        raise ConfigError(f"frames must be at least 1, got {frames}")
    out = Path(out)
    durations: list[float] = []
    messages = frame_messages(scenario, frames, seed, size, image_format, dusk, disparity_every, look)
    final_look = scenario_world(scenario, seed, dusk, look).look
    with RecordingWriter(out, atomic=True) as writer:
        writer.describe(Config().to_dict(), recording_info(scenario, seed, frames, size, disparity_every, final_look))
        for fm in progress(messages, frames, f"simulate {scenario}"):
            stamp = fm.stereo.stamp_ns
            writer.write(key_for("camera/stereo"), fm.stereo, log_time_ns=stamp)
            writer.write(key_for("groundtruth/ego"), fm.ego, log_time_ns=stamp)
            writer.write(key_for("groundtruth/objects"), fm.objects, log_time_ns=stamp)
            if fm.disparity is not None:
                writer.write(key_for("groundtruth/disparity"), fm.disparity, log_time_ns=stamp)
            durations.append(fm.render_s)
    log.info("%s: %d frames, median %.3f s per stereo pair", out, frames, float(np.median(durations)))
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", nargs="?", default="urban", help="scenario name (see --list)")
    parser.add_argument("--out", type=Path, help="recording to write (.mcap)")
    parser.add_argument("--frames", type=int, default=100, help="frames at 10 Hz (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="varies placements, colours and traffic")
    parser.add_argument("--size", default="640x480", help="image size WIDTHxHEIGHT")
    parser.add_argument("--image-format", choices=IMAGE_FORMATS, default="png", help="how images are stored")
    parser.add_argument("--lowtexture", action="store_true", help="dusk look: dark, low contrast, noisy")
    parser.add_argument("--noise", type=float, help="sensor noise sigma in grey levels (scenario default 1.5)")
    parser.add_argument("--blur", type=float, help="optical blur sigma in pixels (scenario default 0.6)")
    parser.add_argument("--exposure-ratio", type=float, help="right gain / left gain (scenario default 1.03)")
    parser.add_argument("--disparity-every", type=int, default=1, metavar="N",
                        help="store true disparity every N-th frame (0: never)")
    parser.add_argument("--list", action="store_true", help="list the scenarios and exit")


def run(args: argparse.Namespace) -> int:
    if args.list:
        for name, scenario in SCENARIOS.items():
            print(f"{name:11s} {scenario.summary}")
        return 0
    if args.scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario {args.scenario!r}; valid: {', '.join(SCENARIOS)}")
    if args.out is None:
        raise ConfigError("--out FILE.mcap is required")
    chosen = {"noise_sigma": args.noise, "blur_sigma": args.blur, "exposure_ratio": args.exposure_ratio}
    look = {k: v for k, v in chosen.items() if v is not None}
    if any(v < 0 for v in look.values()):
        raise ConfigError(f"noise, blur and exposure ratio must not be negative: {look}")
    start = time.perf_counter()
    simulate_to_file(args.scenario, args.out, args.frames, args.seed, parse_size(args.size),
                     args.image_format, args.lowtexture, args.disparity_every, look)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB, {args.frames} frames) "
          f"in {time.perf_counter() - start:.1f} s")
    return 0
