"""The sky: flat image joined to the top row, where no honest disparity exists.

SGM's smoothness carries a near object's disparity into the flat sky beside it, and both views
can agree on the carried value, so a left-right check keeps it. Measured on synthetic `urban`
seed 7: a band of sky above a wall's top edge took a pole's disparity and joined the pole to the
wall 2.3 m behind it in one cluster.

A pixel is sky when a path of flat pixels joins it to the image's top row. Flat means little
gradient in either direction: the matcher's own texture test looks only across (that is what
matching sees), and a horizontal edge, such as a hedge's top against a pale sky or a walker's
head, has no gradient across, so the sky would flood through it into whatever flat surface lies
below.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from services.stereo_depth.sgbm import Image


def sky_mask(image: Image, window: int, max_gradient: float) -> npt.NDArray[np.bool_]:
    """Pixels joined to the top row through pixels whose mean |gradient| (window square) is under ``max_gradient``."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    gradient = np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)) + np.abs(cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3))
    flat = (cv2.blur(gradient, (window, window)) < np.float32(max_gradient)).astype(np.uint8)
    _, labels = cv2.connectedComponents(flat, connectivity=4)
    top = np.unique(labels[0][flat[0] > 0])
    return np.isin(labels, top) if top.size else np.zeros(grey.shape, dtype=bool)
