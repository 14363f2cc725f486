"""Multi-resolution semi-global matching: a half-resolution pass bounds what the full one must do.

The paper's SGM used a multi-resolution scheme. Here a half-resolution pass (an eighth of the
work per disparity range) searches the whole range down to the nearest depth of interest, in
both views; the full-resolution pass searches only the first ``fine_disparities`` pixels, the far
range where sub-pixel precision matters most. Near pixels beyond the fine range take the coarse
value (a half-pixel error at 3 m is 1 % of depth). The fine pass is checked against a
full-resolution right view (``lr_check: full``); checking it against the coarse right view
instead saves that match (about a third of the time) but, measured, leaves 1.5 points less
density on KITTI raw 0009 and Middlebury and 0.15 points more D1-est on Middlebury.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import NamedTuple, TypeVar

import cv2
import numpy as np

from common.config import StereoConfig
from common.errors import ConfigError
from services.stereo_depth.consistency import left_right_check, textured, upsample, within_neighbours
from services.stereo_depth.exposure import contrast_gain
from services.stereo_depth.far_band import MARGIN_PX, FarRegion, merged
from services.stereo_depth.occlusion import fill_hidden
from services.stereo_depth.sgbm import DisparityMap, Image, SgbmParams, SgbmPass, round_up_16
from services.stereo_depth.sky import sky_mask
from services.stereo_depth.subpixel import SubpixelParams, refine_disparity

T = TypeVar("T")

LR_MODES: tuple[str, ...] = ("coarse", "full", "none")
#: coarse pixels this close to the fine range's end are trusted over the fine pass.
NEAR_MARGIN_PX: float = 4.0
#: what ``match`` times: widening the pair (``upsample_x``), both passes, the check, fills, sub-pixel,
#: the far field's widened pass (``upsample_beyond_m``), sky.
STEPS: tuple[str, ...] = ("upsample", "sgbm_coarse", "sgbm_fine", "lr_check", "fill", "subpixel", "far_band", "sky")
#: side of the square over which the texture test averages the grey gradient.
TEXTURE_WINDOW_PX: int = 9


def widened(image: Image, factor: int) -> Image:
    """``image`` ``factor`` times as wide, by OpenCV's cubic interpolation along its rows; every
    ``factor``-th column is an original one, so the disparity of column ``factor * u`` is column ``u``'s.

    Why wider: SGM's penalties and its 3 x 3 block count in pixels. On a widened pair a pole a few
    pixels wide spans twice the pixels that pay for leaving the background's disparity, and is no
    longer drawn towards it (docs/results/voxel.md, "Session 64"). The columns between are each a
    four-tap filter of the row: ``cv2.remap`` onto the same grid gives the same bytes at factor 2 in
    twice the time.
    """
    height, width = image.shape[:2]
    out = np.empty((height, factor * width, *image.shape[2:]), dtype=image.dtype)
    out[:, ::factor] = image
    for phase in range(1, factor):
        t = phase / factor
        taps = np.array([[_cubic(1.0 + t), _cubic(t), _cubic(1.0 - t), _cubic(2.0 - t)]], dtype=np.float32)
        out[:, phase::factor] = cv2.filter2D(image, -1, taps, anchor=(1, 0), borderType=cv2.BORDER_REPLICATE)
    return out


def _cubic(t: float, a: float = -0.75) -> float:
    """OpenCV's cubic interpolation weight at distance ``t`` (its ``INTER_CUBIC`` uses a = -0.75)."""
    t = abs(t)
    if t <= 1.0:
        return (a + 2.0) * t**3 - (a + 3.0) * t**2 + 1.0
    return a * t**3 - 5.0 * a * t**2 + 8.0 * a * t - 4.0 * a


class FarPass(NamedTuple):
    """A widened matcher for where the far field is seen (far_band.py)."""

    matcher: MultiResolutionMatcher
    region: FarRegion


class MultiResolutionMatcher:
    """Disparity of the left image in full-resolution pixels, NaN where no honest value exists."""

    def __init__(
        self,
        fine: SgbmPass,
        coarse: SgbmPass | None,
        lr_check: str,
        lr_max_diff_px: float,
        fill_support_px: int,
        color: bool,
        hidden_fill: tuple[int, int] = (0, 0),
        min_texture: float = 0.0,
        subpixel: SubpixelParams | None = None,
        sky: tuple[int, float, float, int, int] = (0, 0.0, 0.0, 0, 0),
        contrast_span: float = 0.0,
        upsample_x: int = 1,
    ) -> None:
        if lr_check not in LR_MODES:
            raise ConfigError(f"stereo.lr_check {lr_check!r} unknown; allowed: {LR_MODES}")
        if lr_check == "coarse" and coarse is None:
            raise ConfigError("stereo.lr_check 'coarse' needs the half-resolution pass")
        self.fine = fine
        self.coarse = coarse
        self.lr_check = lr_check
        self.lr_max_diff_px = lr_max_diff_px
        self.fill_support_px = fill_support_px
        self.color = color
        self.hidden_colour_step, self.hidden_max_px = hidden_fill
        self.min_texture = min_texture
        self.subpixel = subpixel
        self.sky_window_px, self.sky_max_gradient, self.sky_gap_colour, self.sky_fringe_px, self.sky_underside_px = sky
        self.contrast_span = contrast_span
        if upsample_x < 1:
            raise ConfigError(f"stereo.upsample_x must be 1 or more, not {upsample_x}")
        self.upsample_x = upsample_x
        #: where the far field is matched again widened (``for_range``'s ``far``); None: nowhere
        self.far: FarPass | None = None
        #: the last pair's contrast gain (exposure.py): over 1, a dim pair
        self.last_gain = 1.0
        #: milliseconds of the last ``match`` per step (``STEPS``).
        self.timings_ms: dict[str, float] = {}

    @classmethod
    def for_range(
        cls, cfg: StereoConfig, max_disparity: int, far: FarRegion | None = None
    ) -> MultiResolutionMatcher:
        """Matchers for a search range of ``max_disparity`` full-resolution pixels (a multiple of 16).

        With ``cfg.upsample_x`` over 1 every pass works on images that many times wider, so the range
        and every setting in pixels are in the widened image's pixels. Given ``far`` (where the far
        field is seen, and the disparities to search there; far_band.py), only that part is matched
        widened, after the whole pair is matched as it is.
        """
        if far is not None and cfg.upsample_x > 1:
            whole = cls.for_range(dataclasses.replace(cfg, upsample_x=1), max_disparity)
            far = far._replace(reach_px=min(far.reach_px, max_disparity))
            whole.far = FarPass(cls.for_range(cfg, far.reach_px), far)
            return whole
        wide = max(cfg.upsample_x, 1)  # (under 1 is refused by the constructor)
        max_disparity *= wide
        fine_range = min(round_up_16(cfg.fine_disparities), max_disparity)
        need_coarse = max_disparity > fine_range or cfg.lr_check == "coarse" or cfg.fill_support_px > 0
        channels = 3 if cfg.color_matching else 1

        def params(disparities: int, uniqueness: int) -> SgbmParams:
            area = channels * cfg.block_size * cfg.block_size
            return SgbmParams(
                num_disparities=disparities,
                block_size=cfg.block_size,
                p1=cfg.p1_factor * area,
                p2=cfg.p2_factor * area,
                uniqueness=uniqueness,
                speckle_window=cfg.speckle_window,
                speckle_range=cfg.speckle_range,
                pre_filter_cap=cfg.pre_filter_cap,
                mode=cfg.mode,
                pad_left=cfg.fill_left_border,
            )

        fine = SgbmPass(params(fine_range, cfg.uniqueness))
        # the half-resolution pass stays at half the original image (``_coarse``): over a range in widened pixels
        coarse_range = round_up_16(max_disparity / (2 * wide))
        coarse = SgbmPass(params(coarse_range, cfg.coarse_uniqueness)) if need_coarse else None
        hidden = (cfg.hidden_fill_colour_step, cfg.hidden_fill_max_px)
        subpixel = None
        if cfg.subpixel_iterations > 0:
            subpixel = SubpixelParams(
                window=cfg.subpixel_window,
                iterations=cfg.subpixel_iterations,
                span_px=cfg.subpixel_span_px,
                max_step_px=cfg.subpixel_max_step_px,
                max_disparity_px=cfg.subpixel_max_disparity_px,
            )
        sky = (cfg.sky_window_px, cfg.sky_max_gradient, cfg.sky_gap_colour, cfg.sky_fringe_px, cfg.sky_underside_px)
        return cls(
            fine, coarse, cfg.lr_check, cfg.lr_max_diff_px, cfg.fill_support_px, cfg.color_matching, hidden,
            cfg.min_texture, subpixel, sky, cfg.contrast_span, cfg.upsample_x,
        )  # fmt: skip

    def match(self, left_rgb: Image, right_rgb: Image) -> DisparityMap:
        """The left image's disparity, NaN where none is honest.

        With ``upsample_x`` over 1 the full-resolution pass, its check and the sub-pixel refinement
        run on both images widened that many times (``widened``), and the disparity of each original
        column is read back; the half-resolution pass stays at half the original pair, and hidden
        fill and sky run on the original pair. Against all of it on the widened pair (session 64,
        docs/results/voxel.md): the stage takes 1.86 instead of 2.3 times as long as unwidened, and
        KITTI raw's density is 86.9 instead of 82.5 %, for about the same urban one-cluster.
        Refining sub-pixel on the original pair as well saved 20 ms more but read KITTI tracking
        0001's moving car at 1.05 m/s RMSE instead of 0.46, and held-out urban at 89.6 % one-cluster.
        """
        self.timings_ms = dict.fromkeys(STEPS, 0.0)
        left, right = self._intensity(left_rgb), self._intensity(right_rgb)
        fused = self._unfilled(left, right)
        far = self.far
        # not on a dim pair: widened, the dusk scenario's far field lost more values than it mended
        # (one-cluster 67.2 / 63.8 % against 68.7 / 70.5 on seeds 7 / 8; docs/results/voxel.md, "Session 65")
        if far is not None and self.last_gain <= 1.0:
            fused = self._timed("far_band", lambda: self._with_far_field(far, fused, left, right))
        fused = self._timed("fill", lambda: self._fill_hidden(fused, left))
        return self._timed("sky", lambda: self._drop_sky(fused, left, left_rgb))

    def _unfilled(self, left: Image, right: Image) -> DisparityMap:
        """Matched, checked and refined, before hidden pixels are filled and the sky dropped."""
        wide_left, wide_right, f = left, right, self.upsample_x
        if f > 1:
            wide_left, wide_right = self._timed("upsample", lambda: (widened(left, f), widened(right, f)))
        fused = self._matched(wide_left, wide_right, left, right)
        fused = self._timed("subpixel", lambda: self._refine(fused, wide_left, wide_right))
        if f > 1:
            fused = np.ascontiguousarray(fused[:, ::f] / np.float32(f))
        return fused

    @staticmethod
    def _with_far_field(far: FarPass, disparity: DisparityMap, left: Image, right: Image) -> DisparityMap:
        """The far field matched widened, merged in. Its crop reaches ``MARGIN_PX`` further up, down
        and right for SGM's paths, and the search range further left, so each kept pixel has its whole
        range; all of that is thrown away."""
        far.matcher.timings_ms = dict.fromkeys(STEPS, 0.0)  # (its own steps, within this one's "far_band")
        box = far.region
        height, width = left.shape[:2]
        top, bottom = max(0, box.top - MARGIN_PX), min(height, box.bottom + MARGIN_PX)
        start, end = max(0, box.left - box.reach_px), min(width, box.right + MARGIN_PX)
        crop = (slice(top, bottom), slice(start, end))
        found = far.matcher._unfilled(left[crop], right[crop])
        kept = found[box.top - top : box.bottom - top, box.left - start : box.right - start]
        return merged(disparity, kept, box.top, box.left, box.reach_px)

    def _matched(self, left: Image, right: Image, original_left: Image, original_right: Image) -> DisparityMap:
        """Both SGM passes, checked and fused: the full-resolution one on ``left`` and ``right``, the
        half-resolution one on the original pair halved (the same images, unless widened)."""
        gain = contrast_gain(left, self.contrast_span)  # a dim pair: SGM's penalties scaled down (exposure.py)
        self.last_gain = gain
        for sgbm in (self.fine, self.coarse):
            if sgbm is not None:
                sgbm.scale_penalties(1.0 / gain)
        coarse_left, coarse_right = self._coarse(original_left, original_right, left.shape[:2])
        fine = self._fine(left, right, coarse_right)
        return self._timed("fill", lambda: self._fuse(fine, coarse_left, left))

    def _timed(self, step: str, work: Callable[[], T]) -> T:
        start = time.perf_counter()
        result = work()
        self.timings_ms[step] += (time.perf_counter() - start) * 1000.0
        return result

    def _intensity(self, rgb: Image) -> Image:
        rgb = np.ascontiguousarray(rgb)  # OpenCV refuses views with strided columns
        return rgb if self.color else cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)

    def _coarse(
        self, left: Image, right: Image, shape: tuple[int, ...]
    ) -> tuple[DisparityMap | None, DisparityMap | None]:
        """Both views at half resolution, checked against each other, brought to the full pass's ``shape``
        (and its pixels: ``upsample_x`` times the original's along rows)."""
        if self.coarse is None:
            return None, None

        def half(img: Image) -> Image:
            size = (max(1, img.shape[1] // 2), max(1, img.shape[0] // 2))
            return cv2.resize(img, size, interpolation=cv2.INTER_AREA)

        coarse = self.coarse
        small_left, small_right = half(left), half(right)
        disp_left = self._timed("sgbm_coarse", lambda: coarse.left(small_left, small_right))
        disp_right = self._timed("sgbm_coarse", lambda: coarse.right(small_left, small_right))
        if self.lr_check != "none":
            disp_left = self._timed("lr_check", lambda: left_right_check(disp_left, disp_right, self.lr_max_diff_px))
        scale = shape[1] / small_left.shape[1]
        full = (shape[0], shape[1])
        return self._timed("lr_check", lambda: (upsample(disp_left, full, scale), upsample(disp_right, full, scale)))

    def _fine(self, left: Image, right: Image, coarse_right: DisparityMap | None) -> DisparityMap:
        """The full-resolution pass over the far range, checked against a right view."""
        disp = self._timed("sgbm_fine", lambda: self.fine.left(left, right))
        if self.lr_check == "full":
            disp_right = self._timed("sgbm_fine", lambda: self.fine.right(left, right))
            return self._timed("lr_check", lambda: left_right_check(disp, disp_right, self.lr_max_diff_px))
        if self.lr_check == "coarse" and coarse_right is not None:
            return self._timed("lr_check", lambda: left_right_check(disp, coarse_right, 2.0 * self.lr_max_diff_px))
        return disp

    def _fuse(self, fine: DisparityMap, coarse: DisparityMap | None, left: Image) -> DisparityMap:
        """Near pixels from the coarse pass, the rest from the fine one, holes from the coarse where corroborated.

        Where the image is nearly flat, a fine value must also agree with the coarse pass (whose
        stricter uniqueness leaves such areas empty): the two full-resolution views alone can
        agree on values SGM carried into the sky (measured on the synthetic urban scene: half the
        phantom obstacles came from such sky points).
        """
        if coarse is None:
            return fine
        if self.min_texture > 0:
            with np.errstate(invalid="ignore"):  # NaN never agrees
                agrees = np.abs(fine - coarse) <= 2.0 * self.lr_max_diff_px
            fine = np.where(agrees | textured(left, TEXTURE_WINDOW_PX, self.min_texture), fine, np.float32(np.nan))
        near = coarse >= self.fine.params.num_disparities - NEAR_MARGIN_PX
        fused = np.where(near, coarse, fine)
        if self.fill_support_px > 0:
            holes = np.isnan(fused) & within_neighbours(coarse, fused, self.fill_support_px, self.lr_max_diff_px)
            fused = np.where(holes, coarse, fused)
        return fused.astype(np.float32, copy=False)

    def _refine(self, disparity: DisparityMap, left: Image, right: Image) -> DisparityMap:
        """Sub-pixel parts from the grey images (``subpixel.py``), before hidden pixels are filled.

        Grey, not colour: on synthetic `urban` the two gave the same precision (0.089 against 0.087
        px median absolute error beyond 15 m) and grey takes a quarter of the time. Hidden pixels
        are filled afterwards because the right camera cannot see them, so there is nothing to
        refine them against.
        """
        if self.subpixel is None:
            return disparity
        if self.color:
            left, right = (cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) for img in (left, right))
        return refine_disparity(left, right, disparity, self.subpixel)

    def _drop_sky(self, disparity: DisparityMap, left: Image, left_rgb: Image) -> DisparityMap:
        """NaN over the sky (``sky.py``), last, so no fill puts a value back."""
        if self.sky_window_px <= 0:
            return disparity
        sky = sky_mask(
            left, self.sky_window_px, self.sky_max_gradient, left_rgb, self.sky_gap_colour, disparity,
            fringe_px=self.sky_fringe_px, underside_px=self.sky_underside_px,
        )  # fmt: skip
        return np.where(sky, np.float32(np.nan), disparity).astype(np.float32, copy=False)

    def _fill_hidden(self, disparity: DisparityMap, left: Image) -> DisparityMap:
        """Holes the right camera cannot see, from the surface beside them (see ``occlusion.py``)."""
        if self.hidden_max_px <= 0:
            return disparity
        return fill_hidden(disparity, left, self.hidden_colour_step, self.hidden_max_px)
