"""Procedural surface texture: one tileable noise image with pre-filtered levels.

Every surface is textured by looking this image up at its own metric coordinates (world
coordinates for the ground, object coordinates for objects), so a surface point has the same
colour in both views and in every frame: what a stereo matcher and visual odometry rely on.
Far surfaces read a low-pass level chosen from the pixel's footprint on the surface, which
keeps the two views consistent instead of aliasing differently in each.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit

F32 = npt.NDArray[np.float32]

#: texels per side (a power of two, so wrapping is a mask).
SIZE = 512
#: number of pre-filtered levels; level k keeps detail coarser than 2**k texels.
LEVELS = 8


def _noise_levels(size: int, levels: int) -> F32:
    """Pink-ish noise, periodic by construction (filtered in Fourier space), at every level."""
    rng = np.random.default_rng(20130601)
    white = np.fft.rfft2(rng.standard_normal((size, size)))
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    radius = np.hypot(fx, fy)
    shaped = white / np.maximum(radius, 1.0 / size) ** 0.5
    out = np.empty((levels, size, size), np.float32)
    scale = 1.0
    for level in range(levels):
        cutoff = 0.5 / 2**level
        img = np.fft.irfft2(shaped * np.exp(-0.5 * (radius / (0.5 * cutoff)) ** 2), s=(size, size))
        if level == 0:
            scale = 1.0 / float(img.std())
        out[level] = np.clip(img * scale, -3.0, 3.0)
    return out


class Texture:
    """Bilinear look-ups into the noise levels at metric coordinates."""

    def __init__(self) -> None:
        self._flat = _noise_levels(SIZE, LEVELS).ravel()

    def sample(self, u: F32, v: F32, texel: F32, footprint: F32, phase: F32) -> F32:
        """Noise (about unit deviation at level 0) at ``(u, v)`` metres on a surface.

        ``texel`` is the surface's texel size (m), ``footprint`` the size one pixel covers there,
        ``phase`` a per-surface offset in texels so surfaces of one material do not look cloned.
        """
        out = np.empty(len(u), np.float32)
        _sample(self._flat, u, v, texel, footprint, phase, out)
        return out


@njit(cache=True, nogil=True)
def _sample(flat, u, v, texel, footprint, phase, out):  # pragma: no cover - compiled
    mask = SIZE - 1
    for i in range(len(u)):
        ratio = max(footprint[i] / texel[i], 1.0)
        level = min(max(int(np.rint(np.log2(ratio))), 0), LEVELS - 1)
        x = u[i] / texel[i] + phase[i]
        y = v[i] / texel[i] + phase[i] * 0.37
        x0f, y0f = np.floor(x), np.floor(y)
        fx, fy = x - x0f, y - y0f
        x0, y0 = int(x0f) & mask, int(y0f) & mask
        x1, y1 = (x0 + 1) & mask, (y0 + 1) & mask
        base = level * SIZE * SIZE
        r0, r1 = base + y0 * SIZE, base + y1 * SIZE
        top = flat[r0 + x0] * (1 - fx) + flat[r0 + x1] * fx
        bottom = flat[r1 + x0] * (1 - fx) + flat[r1 + x1] * fx
        out[i] = top * (1 - fy) + bottom * fy
