"""Time per frame of map update + clustering against voxel edge (the paper's Fig. 5).

``stereovox bench`` calls :func:`edge_sweep` on a recording's clouds and egomotion and
:func:`plot_sweep` to draw the result; ``python -m services.voxel_mapper.sweep RUN.mcap`` does the
same from the command line for a recording that holds ``stereo_depth/points`` and ``odometry/ego``
(or ``groundtruth/ego``) messages.
"""

from __future__ import annotations

import argparse
import copy
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from common.config import Config
from common.messages import EgoMotion, PointCloud

#: the paper's Fig. 5 resolutions (its 0.05 m is left out: the map then mirrors the disparity map).
EDGES: tuple[float, ...] = (0.50, 0.25, 0.20, 0.15, 0.10)


def scaled(cfg: Config, edge: float) -> Config:
    """``cfg`` at another voxel edge, its count limits scaled from the 0.25 m defaults they were measured at.

    Points per voxel grow with the face area (edge squared), voxels per object with its inverse, and a
    gap in voxels with the inverse of the edge, so each limit keeps its meaning in metres.
    """
    out = copy.deepcopy(cfg)
    ratio = float(edge) / cfg.voxel.edge
    out.voxel.edge = float(edge)
    out.voxel.min_points_per_voxel = max(1, round(cfg.voxel.min_points_per_voxel * ratio**2))
    out.voxel.min_cluster_voxels = max(1, round(cfg.voxel.min_cluster_voxels / ratio**2))
    out.voxel.bridge_voxels = max(1, round(cfg.voxel.bridge_voxels / ratio))
    return out


def edge_sweep(
    clouds: Sequence[PointCloud], egos: Sequence[EgoMotion], edges: Sequence[float] = EDGES, cfg: Config | None = None
) -> list[dict[str, float]]:
    """Per voxel edge (limits scaled): median wall and CPU milliseconds per frame, clusters and voxels.

    CPU time (this process) is quoted beside wall time because on a shared machine wall time
    mostly measures the neighbours: the two differed by 2-5x while this was measured.
    """
    from services.voxel_mapper.core import VoxelMapper

    base = cfg or Config()
    rows = []
    for edge in edges:
        run_cfg = scaled(base, edge)
        VoxelMapper.from_config(run_cfg).process(clouds[0], egos[0])  # compile / warm caches outside the timing
        mapper = VoxelMapper.from_config(run_cfg)
        times, cpu, counts, voxels = [], [], [], []
        for cloud, ego in zip(clouds, egos, strict=True):
            start, start_cpu = time.perf_counter(), time.process_time()
            out = mapper.process(cloud, ego)
            times.append((time.perf_counter() - start) * 1e3)
            cpu.append((time.process_time() - start_cpu) * 1e3)
            counts.append(len(out.clusters))
            voxels.append(out.voxel_count)
        rows.append(
            {
                "edge_m": float(edge),
                "ms": float(np.median(times)),
                "ms_p95": float(np.percentile(times, 95)),
                "cpu_ms": float(np.median(cpu)),
                "clusters": float(np.median(counts)),
                "voxels": float(np.median(voxels)),
            }
        )
    return rows


def table(rows: Sequence[dict[str, float]]) -> str:
    """The sweep as a Markdown table."""
    lines = [
        "| edge (m) | wall ms / frame (median) | wall p95 | CPU ms / frame (median) | clusters / frame | voxels |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    nan = float("nan")
    for r in rows:
        lines.append(
            f"| {r['edge_m']:.2f} | {r['ms']:.1f} | {r.get('ms_p95', nan):.1f} | {r.get('cpu_ms', nan):.1f} | "
            f"{r['clusters']:.0f} | {r.get('voxels', nan):.0f} |"
        )
    return "\n".join(lines)


def plot_sweep(rows: Sequence[dict[str, float]], path: str | Path, title: str = "") -> Path:
    """Bar chart of ms per frame against voxel edge, clusters per frame on a second axis (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    edges = [f"{r['edge_m']:.2f}" for r in rows]
    where = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    ax.bar(where - 0.2, [r["ms"] for r in rows], width=0.4, color="#9db7d9", label="wall ms (median)")
    ax.bar(where + 0.2, [r.get("cpu_ms", r["ms"]) for r in rows], width=0.4, color="#4a7ab5", label="CPU ms (median)")
    ax.set_xticks(where, edges)
    ax.set_xlabel("voxel edge (m)")
    ax.set_ylabel("ms per frame (median)")
    twin = ax.twinx()
    twin.plot(where, [r["clusters"] for r in rows], "o-", color="#c0504d", label="clusters per frame")
    twin.set_ylabel("clusters per frame (median)")
    ax.set_title(title or "Voxel map + clustering time against voxel edge (cf. the paper's Fig. 5)")
    # below the plot: inside it the second axis's line is drawn over the legend
    handles = ax.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
    fig.legend(handles, [h.get_label() for h in handles], loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0.0, 0.07, 1.0, 1.0))
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def load_inputs(path: str | Path, max_frames: int = 0) -> tuple[list[PointCloud], list[EgoMotion]]:
    """Clouds and their egomotion (odometry's, else ground truth as EgoMotion) paired by frame id."""
    from common.messages import GroundTruthEgo
    from common.recording import open_recording

    clouds: dict[int, PointCloud] = {}
    egos: dict[int, EgoMotion] = {}
    truth: dict[int, EgoMotion] = {}
    for _key, msg in open_recording(path).messages(topics=["stereo_depth/points", "odometry/ego", "groundtruth/ego"]):
        if isinstance(msg, PointCloud):
            clouds[msg.frame_id] = msg
        elif isinstance(msg, EgoMotion):
            egos[msg.frame_id] = msg
        elif isinstance(msg, GroundTruthEgo):
            truth[msg.frame_id] = EgoMotion(frame_id=msg.frame_id, stamp_ns=msg.stamp_ns, pose=msg.pose, valid=True)
    source = egos or truth
    ids = sorted(i for i in clouds if i in source)
    if max_frames:
        ids = ids[:max_frames]
    return [clouds[i] for i in ids], [source[i] for i in ids]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", help="MCAP with stereo_depth/points and odometry/ego or groundtruth/ego")
    parser.add_argument("--png", default="docs/voxel_sweep.png")
    parser.add_argument("--max-frames", type=int, default=0)
    args = parser.parse_args(argv)
    clouds, egos = load_inputs(args.recording, args.max_frames)
    if not clouds:
        print(f"{args.recording}: no point clouds paired with egomotion")
        return 1
    rows = edge_sweep(clouds, egos)
    print(table(rows))
    print(f"plot: {plot_sweep(rows, args.png, title=f'{Path(args.recording).name}, {len(clouds)} frames')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
