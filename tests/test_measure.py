"""The README's pooled table: each scenario's seeds summed, not averaged, and speed error pooled by pairs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import load_script

from common.evaluation.evaluate import evaluate_recording, matched_frames
from common.evaluation.inputs import read_inputs
from common.recording import open_recording
from services.demo import BUNDLED
from services.pipeline import process_file


def run(tp: int, fp: int, fn: int, rmse: float | None, pairs: int, parked: int, tracks: int) -> dict[str, Any]:
    return {
        "moving": {"tp": tp, "fp": fp, "fn": fn},
        "speed": None if rmse is None else {"rmse_mps": rmse, "pairs": pairs},
        "stationary_tracks": {"false_moving": parked, "tracks": tracks},
    }


def test_seeds_are_pooled_by_counts_and_speed_by_pairs() -> None:
    measure = load_script("measure")
    results = {
        "urban-s7": run(9, 0, 1, 1.0, 9, 1, 10),  # 90 % alone
        "urban-s9": run(1, 1, 8, 3.0, 1, 0, 12),  # 10 % alone: a mean of shares would say 50 %
        "crossing-s7": run(5, 0, 5, None, 0, 0, 4),
        "kitti-tracking-0001": run(1, 2, 3, 0.5, 1, 0, 8),  # real data is not a scenario seed
    }
    rows = measure.pooled_table(results).splitlines()
    assert rows[2] == "| urban | 2 | 50.0 / 5.0 / 45.0 | 1.34 | 1 of 22 |"  # sqrt((9 * 1.0^2 + 1 * 3.0^2) / 10)
    assert rows[3] == "| crossing | 1 | 50.0 / 0.0 / 50.0 | - | 0 of 4 |"
    assert len(rows) == 4


def test_runs_of_an_earlier_measurement_are_restarted_with_the_new_settings(tmp_path: Path) -> None:
    """``--from tracker --runs DIR``: the folder's run goes through the tracker again; no scene is rendered."""
    measure = load_script("measure")
    runs, out = tmp_path / "base", tmp_path / "changed"
    runs.mkdir()
    out.mkdir()
    assert process_file(BUNDLED, runs / "urban-s7_run.mcap", max_frames=4, with_frames=False) == 4

    def render(path: Path) -> None:
        raise AssertionError(f"a restart rendered {path}")

    result = measure.measure("urban-s7", render, out, ["tracker.accept_frames=3"], ("tracker", runs))
    assert result is not None and result["frames"] == 4
    assert json.loads((out / "urban-s7.json").read_text()) == result
    restarted = open_recording(out / "urban-s7_run.mcap")
    assert restarted.config_dict()["tracker"]["accept_frames"] == 3
    assert restarted.info()["processed_by"] == "stereovox process --from tracker"
    assert measure.measure("urban-s8", render, out, [], ("tracker", runs)) is None  # not in the folder: left out


def test_a_speed_trace_follows_one_moving_object_frame_by_frame(tmp_path: Path) -> None:
    """scripts/speed_trace.py: the truth's speed and the matched obstacle's, from a run, and its picture."""
    trace = load_script("speed_trace")
    run = tmp_path / "urban_run.mcap"
    assert process_file(BUNDLED, run, max_frames=16, with_frames=False) == 16
    last = matched_frames(read_inputs(run))[-1]
    mover = max(last.truths, key=lambda t: float(np.hypot(*t.velocity[:2])))  # the fastest: a car
    frames, true, seen, moving = trace.trace(run, mover.id)
    assert len(frames) == len(true) == len(seen) == len(moving) and frames[-1] == last.frame_id
    assert true[-1] == pytest.approx(float(np.hypot(*mover.velocity[:2])))
    assert any(moving) and all(abs(s - v) < 3.0 for s, v, m in zip(seen, true, moving, strict=True) if m)
    out = tmp_path / "trace.png"
    argv = ["speed_trace.py", str(run), "--truth", str(mover.id), "--out", str(out)]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("sys.argv", argv)
        assert trace.main() == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_speed_errors_are_the_frames_the_evaluations_rmse_is_taken_over(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """scripts/speed_errors.py: every true moving frame's error, split by the line of sight, as evaluate pairs them."""
    script = load_script("speed_errors")
    run = tmp_path / "urban-s7_run.mcap"
    assert process_file(BUNDLED, run, max_frames=16, with_frames=False) == 16
    speed = evaluate_recording(run)["speed"]
    errors = script.speed_errors(run, [])
    assert len(errors) == speed["pairs"] > 0
    assert script.rms([e.total for e in errors]) == pytest.approx(speed["rmse_mps"])
    parts = [e.along**2 + e.across**2 + e.vertical**2 for e in errors]
    assert parts == pytest.approx([e.total**2 for e in errors])  # the split loses nothing
    assert all(e.range_m > 3.0 and e.true_speed >= 1.0 for e in errors)  # moving objects in the volume
    assert script.main([str(run), "--top", "2"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith(f"{speed['pairs']} true moving frames: RMSE {speed['rmse_mps']:.3f}")
    assert len(printed) == 4 and printed[-1].startswith("these 2 carry")


def test_a_sweep_gives_the_figures_evaluate_gives_the_restarted_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """scripts/sweep_tracker.py: runs read once, the tracker remade per variant, the counts of `--from tracker`."""
    sweep = load_script("sweep_tracker")
    runs = tmp_path / "runs"
    runs.mkdir()
    assert process_file(BUNDLED, runs / "urban-s7_run.mcap", max_frames=16, with_frames=False) == 16
    out = tmp_path / "sweep.json"
    variants = ["--variant", "base", "--variant", "late", "tracker.moving_min_frames=12"]
    assert sweep.main(["--runs", f"held={runs}", *variants, "--json", str(out)]) == 0
    swept = json.loads(out.read_text())
    for name, sets in (("base", []), ("late", ["tracker.moving_min_frames=12"])):
        restarted = tmp_path / f"{name}_run.mcap"
        process_file(runs / "urban-s7_run.mcap", restarted, with_frames=False, resume_from="tracker", sets=sets)
        result = evaluate_recording(restarted)
        moving, still, found = result["moving"], result["stationary"], result["obstacles"]
        got = swept[name]["runs"]["held"]["urban-s7"]
        assert (got["tp"], got["fp"], got["fn"]) == (moving["tp"], moving["fp"], moving["fn"])
        # the counts stationary recall and precision are pooled from, over many runs
        assert got["stationary_matched"] / got["stationary"] == pytest.approx(still["recall"])
        assert got["matched"] / (got["matched"] + got["phantoms"]) == pytest.approx(found["precision"])
        assert got["all_moving_tracks"] == (result["moving_tracks"]["recall"] == 1.0)
    base, late = (swept[n]["runs"]["held"]["urban-s7"] for n in ("base", "late"))
    assert base["tp"] > late["tp"]  # a car is called moving by frame 16 only when tracks may be labelled young
    printed = capsys.readouterr().out.splitlines()
    assert printed[1].startswith("base") and f"held {base['tp']}/{base['fp']}/{base['fn']}" in printed[1]

    # from the mapper: the clusters remade from the points, in two forked workers, and scored too
    coarse = ["voxel.min_cluster_voxels=60"]
    argv = ["--runs", f"held={runs}", "--from", "voxel_mapper", "--jobs", "2", "--json", str(out)]
    assert sweep.main([*argv, "--variant", "base", "--variant", "coarse", *coarse]) == 0
    swept = json.loads(out.read_text())
    for name, sets in (("base", []), ("coarse", coarse)):
        restarted = tmp_path / f"{name}_mapped.mcap"
        process_file(runs / "urban-s7_run.mcap", restarted, with_frames=False, resume_from="voxel_mapper", sets=sets)
        result = evaluate_recording(restarted)
        got = swept[name]["runs"]["held"]["urban-s7"]
        assert (got["tp"], got["fp"], got["fn"]) == tuple(result["moving"][k] for k in ("tp", "fp", "fn"))
        assert got["one_cluster_pct"] == pytest.approx(result["segmentation"]["one_cluster_pct"])
    one = {name: swept[name]["runs"]["held"]["urban-s7"]["one_cluster_pct"] for name in ("base", "coarse")}
    assert one["base"] > one["coarse"]  # clusters under 60 voxels dropped: the far objects have none
