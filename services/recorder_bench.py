"""How fast the recorder stores 640x480 stereo frames: the writer alone, and end to end through Zenoh.

``python -m services.recorder_bench [--frames N] [--images DIR]`` (or :func:`run_bench` from a
future ``stereovox bench``) prints one line per compression and measurement. The writer figure
is what the recorder's writer thread does per message (peek the stamp, chunk, compress, write);
the bus figure runs a real ``stereovox record`` process connected to a router in this process,
publishes frames flat out with BLOCK congestion control and waits until the recorder's Health
says every frame was written or dropped. Images are KITTI frames when ``--images`` names a
folder of PNGs (realistic compression ratios), a textured synthetic pattern otherwise.
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.bus import Publisher, open_session
from common.codec import decode, encode
from common.config import BusConfig
from common.messages import Calibration, Health, StereoFrame, key_for
from common.recording import COMPRESSIONS, RecordingWriter, peek_stamp

WIDTH, HEIGHT = 640, 480


def _images(count: int, image_dir: Path | None) -> list[np.ndarray]:
    """``count`` distinct RGB images of 640x480: KITTI crops if given, else noise on gradients."""
    if image_dir is not None:
        files = sorted(image_dir.glob("*.png"))[:count]
        if files:
            imgs = [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in files]
            return [np.ascontiguousarray(cv2.resize(i, (WIDTH, HEIGHT))) for i in imgs]
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    base = np.stack([xx * 255 // WIDTH, yy * 255 // HEIGHT, (xx + yy) * 127 // (WIDTH + HEIGHT)], -1)
    return [np.clip(base + rng.normal(0, 8, base.shape), 0, 255).astype(np.uint8) for _ in range(min(count, 8))]


def payloads(count: int, image_dir: Path | None = None) -> list[bytes]:
    """Encoded StereoFrames (raw images, ~1.8 MB each) as the bus carries them."""
    imgs = _images(count, image_dir)
    calib = Calibration(fx=700.0, fy=700.0, cx=320.0, cy=240.0, baseline=0.54, width=WIDTH, height=HEIGHT)
    out = []
    for i in range(count):
        left, right = imgs[i % len(imgs)], imgs[(i + 1) % len(imgs)]
        out.append(encode(StereoFrame(frame_id=i, stamp_ns=time.time_ns(), left=left, right=right, calib=calib)))
    return out


def bench_writer(data: list[bytes], compression: str, folder: Path) -> dict[str, Any]:
    """The writer thread's work alone: peek the stamp, write the raw bytes, finish the file."""
    path = folder / f"writer_{compression}.mcap"
    key = key_for("camera/stereo")
    t0 = time.perf_counter()
    with RecordingWriter(path, compression=compression) as w:
        for d in data:
            stamp = peek_stamp(d)
            w.write(key, d, time.time_ns(), stamp[1] if stamp else None)
    elapsed = time.perf_counter() - t0
    size = sum(map(len, data))
    return {"what": "writer", "compression": compression, "frames": len(data), "mb_per_s": size / 1e6 / elapsed,
            "ratio": size / path.stat().st_size}


def _free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def bench_bus(data: list[bytes], compression: str, folder: Path, when_full: str = "drop") -> dict[str, Any]:
    """A real recorder process fed flat out over loopback; MB/s from the first put to the last write."""
    endpoint = _free_endpoint()
    out = folder / f"bus_{compression}_{when_full}.mcap"
    latest: dict[str, Health] = {}
    done = threading.Event()
    with open_session(BusConfig(mode="router", listen=[endpoint])) as session:

        def on_health(sample: Any) -> None:
            h = decode(sample.payload.to_bytes(), Health)
            latest["h"] = h
            if h.detail.get("written_by_topic", {}).get("camera/stereo", 0) + h.dropped >= len(data):
                done.set()

        sub = session.declare_subscriber(key_for("health/recorder"), on_health)
        cmd = [sys.executable, "-m", "services.cli", "record", "--out", str(out), "--connect", endpoint,
               "--compression", compression, "--when-full", when_full, "--set", "health_period_s=0.1"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        try:
            while "ready" not in (proc.stdout.readline() if proc.stdout else "ready"):
                pass
            while "h" not in latest:  # the recorder's session is connected once its Health arrives
                time.sleep(0.01)
            pub = Publisher(session, key_for("camera/stereo"))
            t0 = time.perf_counter()
            for d in data:
                pub.put(d)
            put_s = time.perf_counter() - t0
            done.wait(120)
            elapsed = time.perf_counter() - t0
        finally:
            proc.send_signal(2)
            proc.wait(60)
            sub.undeclare()
    h = latest["h"]
    size = sum(map(len, data))
    written = h.detail.get("written_by_topic", {}).get("camera/stereo", 0)
    return {"what": f"bus/{when_full}", "compression": compression, "frames": len(data), "written": written,
            "dropped": h.dropped, "mb_per_s": written * (size / len(data)) / 1e6 / elapsed,
            "publish_mb_per_s": size / 1e6 / put_s, "callback_us": h.detail.get("callback_us_mean"),
            "write_p50_ms": h.p50_ms, "write_p95_ms": h.p95_ms}


def run_bench(frames: int = 100, compressions: tuple[str, ...] = tuple(COMPRESSIONS), image_dir: Path | None = None,
              repeats: int = 3, when_full: str = "drop") -> list[dict[str, Any]]:
    """Median of ``repeats`` runs per (measurement, compression); the machine is shared and noisy.

    With more frames than the recorder's queue holds (256 MB, ~140 frames) the bus figure is
    the sustained rate: ``drop`` then shows how much a too-slow disk loses, ``block`` how far
    it slows the publisher.
    """
    data = payloads(frames, image_dir)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for compression in compressions:
            for bench in (bench_writer, lambda d, c, f: bench_bus(d, c, f, when_full)):
                runs = [bench(data, compression, folder) for _ in range(repeats)]
                runs.sort(key=lambda r: r["mb_per_s"])
                rows.append(runs[len(runs) // 2] | {"runs_mb_per_s": [round(r["mb_per_s"]) for r in runs]})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--images", type=Path, help="a folder of PNG images (e.g. KITTI image_02/data)")
    parser.add_argument("--compression", action="append", choices=sorted(COMPRESSIONS))
    parser.add_argument("--when-full", choices=("drop", "block"), default="drop")
    args = parser.parse_args()
    rows = run_bench(args.frames, tuple(args.compression or COMPRESSIONS), args.images, args.repeats, args.when_full)
    for row in rows:
        print("  ".join(f"{k}={v:.1f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()), flush=True)


if __name__ == "__main__":
    main()
