"""`stereovox render`: each track's box lands where the camera model puts it, in its state's colour."""

from __future__ import annotations

import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import REPO, stereovox_cmd
from tiny_run import CALIB, GREY, HEIGHT, MOVING, STATIONARY, WIDTH, ego_pose, write_run

from common import messages as sv
from common.errors import InputError
from common.overlay import TRUTH
from common.recording import RecordingWriter
from services.render import parse_range, render_recording


def pixel_of(world: list[float], frame: int) -> tuple[int, int]:
    """Where the pinhole model puts a world point at this frame's ego pose (written out by hand)."""
    pose = ego_pose(frame)
    vehicle = pose[:3, :3].T @ (np.asarray(world, dtype=np.float64) - pose[:3, 3])
    c2v = CALIB.cam_to_vehicle
    cam = c2v[:3, :3].T @ (vehicle - c2v[:3, 3])
    assert cam[2] > 1.0, "test point must lie in front of the camera"
    return round(CALIB.fx * cam[0] / cam[2] + CALIB.cx), round(CALIB.fy * cam[1] / cam[2] + CALIB.cy)


def colour_near(rgb: np.ndarray, uv: tuple[int, int], radius: int = 1) -> np.ndarray:
    """The most saturated pixel around ``uv`` (lines are anti-aliased, projections rounded)."""
    u, v = uv
    patch = rgb[v - radius : v + radius + 1, u - radius : u + radius + 1].reshape(-1, 3).astype(int)
    return patch[np.argmax(patch.max(axis=1) - patch.min(axis=1))]


def is_red(c: np.ndarray) -> bool:
    return c[0] > 180 and c[1] < 90 and c[2] < 90


def is_green(c: np.ndarray) -> bool:
    return c[1] > 160 and c[0] < 90 and c[2] < 110


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("render")
    run = write_run(tmp / "run.mcap", frames=3)
    proc = subprocess.run(
        stereovox_cmd("render", str(run), "--out", str(tmp / "out"), "--video"),
        capture_output=True, text=True, cwd=REPO, timeout=120,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "render: 3 frames" in proc.stdout
    return tmp / "out"


@pytest.mark.timeout(150)
@pytest.mark.parametrize("frame", [0, 2])
def test_boxes_are_drawn_where_the_camera_projects_them(rendered: Path, frame: int) -> None:
    bgr = cv2.imread(str(rendered / f"frame_{frame:06d}.png"))
    assert bgr is not None and bgr.shape == (HEIGHT, WIDTH + HEIGHT, 3)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    lo, hi = MOVING.bbox_min, MOVING.bbox_max
    mid_y, mid_z = (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2
    # the near face of the moving track: bottom edge and the vertical edge nearer the road centre
    for point in ([lo[0], mid_y, lo[2]], [lo[0], lo[1], mid_z]):
        c = colour_near(rgb, pixel_of(point, frame))
        assert is_red(c), f"frame {frame}: expected red at {pixel_of(point, frame)} ({point}), got {c}"
    s_lo, s_hi = STATIONARY.bbox_min, STATIONARY.bbox_max
    c = colour_near(rgb, pixel_of([s_lo[0], (s_lo[1] + s_hi[1]) / 2, s_lo[2]], frame))
    assert is_green(c), f"frame {frame}: expected the stationary box green, got {c}"
    # away from every box the flat image is untouched
    u, v = pixel_of([lo[0], 0.0, 0.3], frame)
    assert np.all(np.abs(rgb[v, u].astype(int) - GREY) <= 3), rgb[v, u]


@pytest.mark.timeout(150)
def test_birds_eye_panel_shows_the_track_footprint_in_the_vehicle_frame(rendered: Path) -> None:
    rgb = cv2.cvtColor(cv2.imread(str(rendered / "frame_000002.png")), cv2.COLOR_BGR2RGB)
    pose = ego_pose(2)
    lo, hi = MOVING.bbox_min, MOVING.bbox_max
    near_edge_mid = pose[:3, :3].T @ (np.array([lo[0], (lo[1] + hi[1]) / 2, 0.0]) - pose[:3, 3])
    scale = HEIGHT / 45.0  # 40 m ahead + 5 m behind over the panel's height
    u = WIDTH + round(HEIGHT / 2 - near_edge_mid[1] * scale)
    v = round(HEIGHT - (near_edge_mid[0] + 5.0) * scale)
    assert is_red(colour_near(rgb, (u, v))), colour_near(rgb, (u, v))


@pytest.mark.timeout(60)
def test_the_truth_written_after_a_frames_obstacles_is_drawn_too(tmp_path: Path) -> None:
    """``process`` writes a frame's ground truth after the stages' outputs: the last frame's too."""
    lone = sv.GroundTruthObject(id=2, cls="pole", center=np.array([20.0, -6.0, 2.0]), size=np.array([2.0, 2.0, 4.0]),
                                yaw=0.0, velocity=np.zeros(3), moving=False)
    run = write_run(tmp_path / "run.mcap", frames=3, extra_truth=(lone,))
    renderer = render_recording(run, tmp_path / "out", parse_range("1:3"))
    assert [p.name for p in renderer.written] == ["frame_000001.png", "frame_000002.png"]
    for frame in (1, 2):
        rgb = cv2.cvtColor(cv2.imread(str(tmp_path / "out" / f"frame_{frame:06d}.png")), cv2.COLOR_BGR2RGB)
        pose = ego_pose(frame)
        scale = HEIGHT / 45.0
        for corner in ([19.0, -7.0], [21.0, -5.0]):  # opposite corners of the lone object's outline
            x, y, _ = pose[:3, :3].T @ (np.array([*corner, 0.0]) - pose[:3, 3])
            u, v = WIDTH + round(HEIGHT / 2 - y * scale), round(HEIGHT - (x + 5.0) * scale)
            patch = rgb[v - 1 : v + 2, u - 1 : u + 2].reshape(-1, 3).astype(int)
            assert (np.abs(patch - TRUTH).max(axis=1) <= 40).any(), f"frame {frame}: no truth outline at {(u, v)}"


@pytest.mark.timeout(150)
def test_video_and_frame_ranges(rendered: Path, tmp_path: Path) -> None:
    video = rendered / "render.mp4"
    assert video.stat().st_size > 1000
    capture = cv2.VideoCapture(str(video))
    count = 0
    while capture.read()[0]:
        count += 1
    capture.release()
    assert count == 3
    run = write_run(tmp_path / "run.mcap", frames=4)
    renderer = render_recording(run, tmp_path / "out", parse_range("1:3"))
    assert [p.name for p in renderer.written] == ["frame_000001.png", "frame_000002.png"]
    assert parse_range("2:") == (2, parse_range(None)[1])
    assert parse_range("5") == (5, 6)
    with pytest.raises(InputError):
        parse_range("3:1")
    with pytest.raises(InputError):
        parse_range("a:b")


@pytest.mark.timeout(60)
def test_a_run_without_camera_frames_renders_nothing_and_says_so(tmp_path: Path) -> None:
    path = tmp_path / "tracks_only.mcap"
    with RecordingWriter(path) as writer:
        writer.write(sv.key_for("tracker/obstacles"), sv.Obstacles(frame_id=0, stamp_ns=1, obstacles=[MOVING]))
    proc = subprocess.run(stereovox_cmd("render", str(path), "--out", str(tmp_path / "out")),
                          capture_output=True, text=True, cwd=REPO, timeout=45)
    assert proc.returncode == 1
    assert "no frame" in proc.stderr and "camera image" in proc.stderr
    assert not list((tmp_path / "out").glob("*.png"))


@pytest.mark.timeout(60)
def test_a_truncated_run_renders_its_readable_part_and_says_where_it_ends(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    whole = write_run(tmp_path / "run.mcap", frames=8).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: int(len(whole) * 0.7)])  # a recorder killed mid-write
    renderer = render_recording(cut, tmp_path / "out")
    assert 0 < len(renderer.written) < 8
    err = capsys.readouterr().err
    assert str(cut) in err and "ends early" in err and "readable part" in err
