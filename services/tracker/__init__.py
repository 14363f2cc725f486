"""Tracker (step 5): greedy association, three queues and a Kalman filter per obstacle."""

from services.tracker.core import Tracker

__all__ = ["Tracker"]
