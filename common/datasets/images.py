"""Stereo image pairs from dataset folders: matched by name, read as RGB, refused loudly.

A dataset whose left and right folders disagree (a frame missing on one side) would pair the
wrong images silently from that frame on, so counts and names are checked before anything is
written; an unreadable PNG names its file.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import InputError

U8 = npt.NDArray[np.uint8]


def image_files(folder: Path, suffix: str = ".png") -> list[Path]:
    """The folder's images in name order (KITTI names are zero-padded frame numbers)."""
    if not folder.is_dir():
        raise InputError(f"{folder}: image folder missing")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() == suffix)


def paired_files(left: Path, right: Path, suffix: str = ".png") -> list[tuple[Path, Path]]:
    """Left and right images of every frame; both folders must hold the same frame names."""
    lefts, rights = image_files(left, suffix), image_files(right, suffix)
    if len(lefts) != len(rights):
        raise InputError(f"{left} has {len(lefts)} images but {right} has {len(rights)}: "
                         "left/right frame counts differ")
    for a, b in zip(lefts, rights, strict=True):
        if a.name != b.name:
            raise InputError(f"{a} is paired with {b}: left/right frame names differ")
    if not lefts:
        raise InputError(f"{left}: no {suffix} images")
    return list(zip(lefts, rights, strict=True))


def read_rgb(path: Path) -> U8:
    """An 8-bit RGB image (grey images are expanded to three channels)."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_pair(left: Path, right: Path) -> tuple[U8, U8]:
    """A rectified pair; both views must have the same size."""
    a, b = read_rgb(left), read_rgb(right)
    if a.shape != b.shape:
        raise InputError(f"{left} is {a.shape[1]}x{a.shape[0]} but {right} is {b.shape[1]}x{b.shape[0]}")
    return a, b


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image, read once to fill the calibration."""
    image = read_rgb(path)
    return int(image.shape[1]), int(image.shape[0])
