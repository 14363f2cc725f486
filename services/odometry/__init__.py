"""Stereo visual odometry: the pure core (the bus shell lives in ``service.py``)."""

from services.odometry.core import StereoOdometry

__all__ = ["StereoOdometry"]
