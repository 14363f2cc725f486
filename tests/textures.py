"""Surface textures for stereo pairs the tests build."""

from __future__ import annotations

import cv2
import numpy as np


def blob_texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Blob texture with detail at several scales, like a real surface (not per-pixel noise)."""
    out = np.zeros((height, width, 3), np.float32)
    for cell, weight in ((2, 0.5), (6, 0.3), (16, 0.2)):
        coarse = rng.uniform(0, 255, (height // cell + 2, width // cell + 2, 3)).astype(np.float32)
        out += weight * cv2.resize(coarse, None, fx=cell, fy=cell, interpolation=cv2.INTER_LINEAR)[:height, :width]
    return out.clip(0, 255).astype(np.uint8)
