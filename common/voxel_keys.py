"""One int64 per voxel: integer coordinates (i, j, k) in 21 bits each, offset to be non-negative.

The voxel map hashes these keys and the tracker compares clusters' voxels by them; both must pack
alike, so the layout lives here once.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

BITS = 21
OFFSET = 1 << (BITS - 1)  # coordinates in [-OFFSET, OFFSET) fit
FIELD = (1 << BITS) - 1


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
