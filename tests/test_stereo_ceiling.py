"""scripts/stereo_ceiling.py: the stereo stage's disparity handed to the truth, in whole or near depth steps."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))

from stereo_ceiling import Variant, handed, main, near_steps, run_one, slug  # noqa: E402


def step_scene() -> tuple[np.ndarray, np.ndarray]:
    """A true map with one depth step at column 20 (10 px left, 5 px right), and a matcher 0.7 px off everywhere."""
    truth = np.full((8, 40), 5.0, dtype=np.float32)
    truth[:, :20] = 10.0
    return truth, truth + np.float32(0.7)


def test_only_pixels_near_a_true_step_are_handed_to_the_truth_or_dropped() -> None:
    truth, matcher = step_scene()
    near = near_steps(truth, 3)
    assert near[:, 16:24].all() and not near[:, :16].any() and not near[:, 24:].any()  # 3 px from columns 19 | 20
    mended = handed(Variant("t", steps="truth", reach_px=3), matcher, truth, 0)
    assert np.array_equal(mended[:, 16:24], truth[:, 16:24])
    assert np.array_equal(mended[:, :16], matcher[:, :16]) and np.array_equal(mended[:, 24:], matcher[:, 24:])
    dropped = handed(Variant("d", steps="drop", reach_px=3), matcher, truth, 0)
    assert np.isnan(dropped[:, 16:24]).all() and np.array_equal(dropped[:, 24:], matcher[:, 24:])
    road = np.repeat(np.arange(40, dtype=np.float32)[:, None] * 0.27, 30, axis=1)  # 0.27 px a row: a slope
    assert not near_steps(road, 3).any()
    assert np.array_equal(handed(Variant("m"), matcher, truth, 0), matcher)


def test_near_a_step_the_matchers_pixels_between_the_surfaces_and_on_the_wrong_one_are_told_apart() -> None:
    truth, _ = step_scene()
    matcher = truth.copy()
    matcher[:, 19] = 7.5  # the 10 px surface read halfway down the step
    matcher[:, 21] = 10.0  # the 5 px surface read as the nearer one: the foreground fattened
    matcher[:, 2] = 7.5  # far from any step: neither variant touches it
    between = handed(Variant("b", steps="between", reach_px=3), matcher, truth, 0)
    flipped = handed(Variant("f", steps="flipped", reach_px=3), matcher, truth, 0)
    assert np.array_equal(between[:, 19], truth[:, 19]) and np.array_equal(between[:, 21], matcher[:, 21])
    assert np.array_equal(flipped[:, 21], truth[:, 21]) and np.array_equal(flipped[:, 19], matcher[:, 19])
    assert (between[:, 2] == 7.5).all() and (flipped[:, 2] == 7.5).all()
    assert slug(Variant("truth + noise, low limits")) == "truth_plus_noise_low_limits"


def test_the_truths_noise_is_unbiased_of_its_sigma_and_the_same_for_a_frame() -> None:
    truth = np.full((200, 200), 8.0, dtype=np.float32)
    noisy = handed(Variant("n", source="truth", noise_px=0.25), None, truth, 7)
    assert float(np.mean(noisy - truth)) == pytest.approx(0.0, abs=0.01)
    assert float(np.std(noisy - truth)) == pytest.approx(0.25, rel=0.03)
    assert np.array_equal(noisy, handed(Variant("n", source="truth", noise_px=0.25), None, truth, 7))
    assert not np.array_equal(noisy, handed(Variant("n", source="truth", noise_px=0.25), None, truth, 8))


def test_a_run_given_the_true_disparity_scores_no_stereo_error(urban_recording: Path, tmp_path: Path) -> None:
    """Through ``process`` and ``evaluate``: the patch reaches the stereo stage, and only while it runs."""
    truth = run_one(Variant("truth", source="truth"), urban_recording, tmp_path / "truth", max_frames=3)
    matcher = run_one(Variant("matcher"), urban_recording, tmp_path / "matcher", max_frames=3)
    assert truth["frames"] == matcher["frames"] == 3
    assert truth["stereo"]["d1_all_pct"] == 0.0
    assert matcher["stereo"]["d1_all_pct"] > 0.0
    assert (tmp_path / "truth" / "urban_run.mcap").exists()


def test_a_recording_without_truth_for_a_frame_is_named(tmp_path: Path) -> None:
    """The bundled recording holds the true disparity of every 4th frame only."""
    with pytest.raises(ValueError, match="frame 1 has no true disparity"):
        run_one(Variant("truth", source="truth"), REPO / "recordings" / "urban.mcap", tmp_path, max_frames=2)


def test_holes_wrong_pixels_and_a_perfect_choice_of_plateau_near_a_step() -> None:
    """The oracles of session 63: the truth in the matcher's holes, its wrong pixels near a step left out,
    or moved onto whichever of its own two plateaus lies nearer the truth."""
    truth, _ = step_scene()
    matcher = truth.copy()
    matcher[:, 19] = 7.5  # between the surfaces
    matcher[:, 21] = 9.8  # the far surface read near the foreground's
    matcher[:, 5] = np.nan  # a hole far from the step
    matcher[:, 30] = 6.0  # 1 px off, but far from the step: no near-step variant touches it
    holes = handed(Variant("h", holes=True), matcher, truth, 0)
    assert (holes[:, 5] == 10.0).all() and (holes[:, 19] == 7.5).all()
    dropped = handed(Variant("w", steps="drop wrong", reach_px=3), matcher, truth, 0)
    assert np.isnan(dropped[:, [19, 21]]).all() and np.isnan(dropped[:, 5]).all()  # the hole stays one
    assert np.array_equal(dropped[:, 16:19], truth[:, 16:19]) and (dropped[:, 30] == 6.0).all()
    matcher[3, 20:30] = 6.0  # a row whose far plateau is itself 1 px off: no plateau is right, the pixels stay
    snap = handed(Variant("s", steps="snap", reach_px=3), matcher, truth, 0)
    assert (snap[:, 19] == 10.0).all()  # the near plateau (10 px) is the truth there
    assert (snap[[0, 1, 2, 4, 5, 6, 7], 21] == 5.0).all()  # the far one (5 px)
    assert (snap[3, 20:24] == 6.0).all()
    assert (snap[:, 30] == 6.0).all() and np.array_equal(snap[4:, 22:26], truth[4:, 22:26])
    right = matcher.copy()
    right[:, 18] = 9.7  # right enough (0.3 px off): in the square as along the row, it stays as the matcher has it
    square = handed(Variant("q", steps="snap square", reach_px=3), right, truth, 0)
    assert (square[:, 18] == 9.7).all() and (square[[0, 1, 2, 4, 5, 6, 7], 21] == 5.0).all()


def test_summarise_joins_variants_run_apart_in_the_variants_order(tmp_path: Path) -> None:
    """``--summarise``: the table of folders filled by different runs, without running anything."""
    assert main(["--out", str(tmp_path), "--summarise"]) == 1  # nothing there yet
    for name, shares in (("truth_in_holes", (80.0, 90.0)), ("matcher", (70.0, 74.0))):
        (tmp_path / name).mkdir()
        for k, one in enumerate(shares):
            seg = {"one_cluster_pct": one, "split_pct": 1.0, "missed_pct": 100.0 - one - 1.0, "merged_pct": 5.0}
            moving = {"tp": 10, "fp": k, "fn": 2}
            (tmp_path / name / f"urban-s{k}.json").write_text(json.dumps({"segmentation": seg, "moving": moving}))
    assert main(["--out", str(tmp_path), "--summarise"]) == 0
    rows = (tmp_path / "summary.md").read_text().splitlines()[2:]
    assert rows == [
        "| matcher | 72.0 | 1.0 | 27.0 | 5.0 | 20 / 1 / 4 |",
        "| truth in holes | 85.0 | 1.0 | 14.0 | 5.0 | 20 / 1 / 4 |",
    ]
    assert (tmp_path / "ceiling.png").stat().st_size > 0
