"""Evaluation of reconstructions against datasets with ground-truth normals (C3VD's layout)."""

from simtest.evaluate.c3vd import C3VDError, C3VDFrame, GroundTruth, load_frame, scan_sequence
from simtest.evaluate.score import estimator_normals, score_highlights, summarise

__all__ = ["C3VDError", "C3VDFrame", "GroundTruth", "estimator_normals", "load_frame", "scan_sequence",
           "score_highlights", "summarise"]
