"""Stereo depth (step 1): semi-global matching and reprojection to coloured 3D points."""

from services.stereo_depth.core import StereoDepth

__all__ = ["StereoDepth"]
