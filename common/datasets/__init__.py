"""Importers of real stereo datasets (KITTI raw, tracking, odometry; Middlebury) into recordings."""
