"""``stereovox render RUN.mcap --out DIR [--frames A:B] [--video]``: pictures like the paper's figures.

Each frame becomes one PNG: the left camera image with every tracked obstacle's 3D box projected
onto it (red moving, green stationary) and its velocity arrow, beside a bird's-eye panel with the
clusters' voxels, the tracks, the true objects (when the recording has them) and the ego path.
``--video`` also writes ``DIR/render.mp4``. The recording is read once, in file order, keeping
only the frames still waiting for their tracker output, so long runs render in bounded memory.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common import messages as sv
from common.codec import decode
from common.errors import InputError
from common.geometry import invert
from common.overlay import BirdsEye, draw_track_on_image, world_to_camera
from common.progress import progress
from common.recording import open_recording, peek_stamp

NEEDED = ("camera/stereo", "voxel_mapper/clusters", "groundtruth/objects", "tracker/obstacles")
#: zlib level of the PNGs: writing dominated the time per frame at OpenCV's default (3); level 1
#: wrote a 1120x480 frame ~25 % faster at about the same size (measured here).
PNG_LEVEL = 1
#: frames kept waiting for their obstacles before the oldest is given up (the tracker dropped it).
MAX_PENDING = 64


@dataclass
class FrameParts:
    """What one frame id has gathered so far from the recording."""

    camera: sv.StereoFrame | None = None
    clusters: sv.Clusters | None = None
    truth: sv.GroundTruthObjects | None = None
    obstacles: sv.Obstacles | None = None
    trajectory: np.ndarray | None = None  # the vehicle's path up to this frame (world positions)
    extra: dict[str, Any] = field(default_factory=dict)


def parse_range(text: str | None) -> tuple[int, int]:
    """``A:B`` -> frame ids A <= id < B; either side may be left out."""
    if not text:
        return 0, sys.maxsize
    start, sep, stop = text.partition(":")
    try:
        a = int(start) if start else 0
        b = int(stop) if stop else (sys.maxsize if sep else a + 1)
    except ValueError:
        raise InputError(f"--frames must look like A:B (frame ids), got {text!r}") from None
    if b <= a:
        raise InputError(f"--frames {text!r} selects no frame (B must be greater than A)")
    return a, b


def compose(parts: FrameParts, obstacles: sv.Obstacles, trajectory: np.ndarray) -> np.ndarray:
    """The picture of one frame (RGB): overlaid left image beside the bird's-eye panel."""
    assert parts.camera is not None
    frame = parts.camera
    image = np.array(frame.left, copy=True)
    world_cam = world_to_camera(obstacles.ego_pose, frame.calib)
    tracked = [o for o in obstacles.obstacles if o.state == "tracked"]
    for ob in sorted(tracked, key=lambda o: -float(np.linalg.norm(o.centroid - obstacles.ego_pose[:3, 3]))):
        draw_track_on_image(image, ob, world_cam, frame.calib)
    moving = sum(o.moving for o in tracked)
    header = f"frame {frame.frame_id}  tracked {len(tracked)} ({moving} moving)"
    (w, h), _ = cv2.getTextSize(header, cv2.FONT_HERSHEY_SIMPLEX, 0.55, 1)
    cv2.rectangle(image, (4, 4), (12 + w, 12 + h + 4), (0, 0, 0), -1)  # legible on sky and on road
    cv2.putText(image, header, (8, 8 + h), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    view = BirdsEye(size_px=image.shape[0])
    panel = view.canvas()
    world_vehicle = invert(np.asarray(obstacles.ego_pose, dtype=np.float64))
    if parts.clusters is not None:
        view.draw_voxels(panel, parts.clusters.clusters, parts.clusters.voxel_edge, world_vehicle)
    if parts.truth is not None:
        view.draw_truth(panel, parts.truth.objects, world_vehicle)
    view.draw_trajectory(panel, trajectory, world_vehicle)
    view.draw_tracks(panel, obstacles.obstacles, world_vehicle)
    return np.hstack([image, panel])


class Renderer:
    """Writes each finished frame as a PNG (and a video frame); counts what it wrote."""

    def __init__(self, out: Path, video: bool, fps: float) -> None:
        self.out = out
        self.video_path = out / "render.mp4" if video else None
        self.fps = fps
        self._writer: cv2.VideoWriter | None = None
        self.written: list[Path] = []
        self.seconds = 0.0

    def write(self, parts: FrameParts, obstacles: sv.Obstacles, trajectory: np.ndarray) -> None:
        started = time.perf_counter()
        bgr = cv2.cvtColor(compose(parts, obstacles, trajectory), cv2.COLOR_RGB2BGR)
        path = self.out / f"frame_{obstacles.frame_id:06d}.png"
        if not cv2.imwrite(str(path), bgr, [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL]):
            raise InputError(f"cannot write {path}")
        self.written.append(path)
        if self.video_path is not None:
            if self._writer is None:
                fourcc = cv2.VideoWriter_fourcc(*"mp4v")
                self._writer = cv2.VideoWriter(str(self.video_path), fourcc, self.fps, (bgr.shape[1], bgr.shape[0]))
            self._writer.write(bgr)
        self.seconds += time.perf_counter() - started

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()


def render_recording(run: Path, out: Path, frames: tuple[int, int] = (0, sys.maxsize), video: bool = False) -> Renderer:
    """Render every frame of ``run`` in ``frames`` that has a camera image and tracker output."""
    reader = open_recording(run)
    info = reader.info()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {out}: {exc.strerror}") from None
    renderer = Renderer(out, video, float(info.get("frame_rate_hz") or 10.0))
    first, stop = frames
    pending: dict[int, FrameParts] = {}
    positions: list[np.ndarray] = []
    last_pose_frame, epoch = -1, 0
    keys = {sv.key_for(t): t for t in NEEDED}
    total = info.get("frames") if isinstance(info.get("frames"), int) else None
    records = progress(
        reader.raw(keys), total, f"render {run.name}", counts=lambda r: r.key.endswith("tracker/obstacles")
    )

    def write_ready(before: int) -> None:
        """Draw every frame older than ``before`` that has its image and obstacles; forget the rest."""
        for fid in sorted(f for f in pending if f < before):
            parts = pending.pop(fid)
            if parts.camera is not None and parts.obstacles is not None and parts.trajectory is not None:
                renderer.write(parts, parts.obstacles, parts.trajectory)

    try:
        for rec in records:
            topic = keys.get(rec.key)
            stamp = peek_stamp(rec.data)
            if topic is None or stamp is None:
                continue
            if topic == "tracker/obstacles" and stamp[0] >= stop:
                break  # tracker output comes in frame order: nothing later is wanted
            if topic != "tracker/obstacles" and not first <= stamp[0] < stop:
                continue
            msg = decode(rec.data)
            if isinstance(msg, sv.Obstacles):
                if msg.world_epoch != epoch:  # the world was re-anchored: the old path is in another frame
                    epoch = msg.world_epoch
                    positions.clear()
                if msg.frame_id != last_pose_frame:  # the path the vehicle took, every frame counted
                    last_pose_frame = msg.frame_id
                    positions.append(np.asarray(msg.ego_pose)[:3, 3].copy())
                # a frame's truth may follow its obstacles (``process`` writes it after the
                # stages' outputs), so a frame is drawn once the next frame's obstacles are in
                write_ready(msg.frame_id)
                if not first <= msg.frame_id < stop:
                    continue
            parts = pending.setdefault(msg.frame_id, FrameParts())
            if isinstance(msg, sv.Obstacles):
                parts.obstacles, parts.trajectory = msg, np.array(positions)
            elif isinstance(msg, sv.StereoFrame):
                parts.camera = msg
            elif isinstance(msg, sv.Clusters):
                parts.clusters = msg
            elif isinstance(msg, sv.GroundTruthObjects):
                parts.truth = msg
            while len(pending) > MAX_PENDING:
                del pending[min(pending)]
        write_ready(sys.maxsize)
    finally:
        renderer.close()
    if reader.truncated is not None:
        print(f"render: {reader.truncated}; rendered the readable part", file=sys.stderr)
    return renderer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="a run recording with camera frames (process or demo)")
    parser.add_argument("--out", type=Path, required=True, help="folder for the PNGs (and render.mp4)")
    parser.add_argument("--frames", default=None, metavar="A:B", help="frame ids A <= id < B (default all)")
    parser.add_argument("--video", action="store_true", help="also write DIR/render.mp4 (mp4v)")


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    renderer = render_recording(args.run, args.out, parse_range(args.frames), args.video)
    n = len(renderer.written)
    if n == 0:
        print(f"render: no frame of {args.run} has both a camera image and tracker output", file=sys.stderr)
        return 1
    elapsed = time.perf_counter() - started
    print(f"render: {n} frames -> {args.out} in {elapsed:.1f} s "
          f"({1000 * renderer.seconds / n:.1f} ms per frame drawing and writing, "
          f"{1000 * elapsed / n:.1f} ms per frame with reading)")
    if renderer.video_path is not None:
        print(f"render: video {renderer.video_path}")
    return 0
