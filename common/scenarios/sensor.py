"""What a real camera adds to a perfect rendering: optical blur, exposure gain, sensor noise.

The left and right gains differ slightly (``Look.exposure_ratio``), as two real sensors do, so a
matcher that relies on equal brightness is tested honestly. Noise comes from the caller's
generator, seeded per frame, so a recording is reproducible byte for byte.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from common.scenarios.world import Look


def expose(image: npt.NDArray[np.float32], gain: float, look: Look, rng: np.random.Generator) -> npt.NDArray[np.uint8]:
    """Linear RGB 0..1 (HxWx3) to an 8-bit image as a sensor with this gain would record it."""
    img = image * np.float32(255.0 * gain)
    if look.blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), look.blur_sigma)
    if look.noise_sigma > 0:
        img = img + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(look.noise_sigma)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
