"""One int64 per voxel: integer coordinates (i, j, k) in 21 bits each, offset to be non-negative.

The voxel map hashes these keys and the tracker compares clusters' voxels by them; both must pack
alike, so the layout lives here once.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

BITS = 21
OFFSET = 1 << (BITS - 1)  # coordinates in [-OFFSET, OFFSET) fit
FIELD = (1 << BITS) - 1
#: Fibonacci hashing's multiplier: a key times it, shifted down, is a table slot (``bucket``).
GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def pack_cells(cells: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Keys (K,) of integer voxel coordinates (Kx3)."""
    c = np.asarray(cells, dtype=np.int64).reshape(-1, 3) + OFFSET
    return (c[:, 0] << (2 * BITS)) | (c[:, 1] << BITS) | c[:, 2]


def unpack(keys: npt.ArrayLike) -> npt.NDArray[np.int32]:
    """Integer voxel coordinates (Kx3 int32) of packed keys."""
    k = np.asarray(keys, dtype=np.int64)
    out = np.empty((k.shape[0], 3), dtype=np.int32)
    out[:, 0] = (k >> (2 * BITS)) - OFFSET
    out[:, 1] = ((k >> BITS) & FIELD) - OFFSET
    out[:, 2] = (k & FIELD) - OFFSET
    return out


@numba.njit(cache=True, inline="always")
def pack(i: int, j: int, k: int) -> int:
    """One voxel's key, in compiled code (``pack_cells`` packs many in numpy)."""
    return ((i + OFFSET) << (2 * BITS)) | ((j + OFFSET) << BITS) | (k + OFFSET)


@numba.njit(cache=True, inline="always")
def bucket(key: int, shift: int) -> int:
    """Where a key starts its probe in an open-addressing table of ``2 ** (64 - shift)`` slots."""
    return np.int64((np.uint64(key) * GOLDEN) >> np.uint64(shift))
