"""Synthetic stereo driving scenarios with exact ground truth (``stereovox simulate``)."""
