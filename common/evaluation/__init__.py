"""Scoring a run against its ground truth, exactly as EVALUATION.md defines every figure."""
