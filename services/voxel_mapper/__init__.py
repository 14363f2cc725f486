"""Voxel mapping and colour flood-fill clustering (the paper's steps 3 and 4)."""

from services.voxel_mapper.core import VoxelMapper

__all__ = ["VoxelMapper"]
