"""Reconstruction of surface normals from specular isophotes (Makki and Bartoli).

Pure numpy / scikit-image / OpenCV: this package never imports Mitsuba or the renderer, so it runs
on real endoscopic images. Entry points:

- :func:`reconstruct` (whole image: detect highlights, then one estimate per highlight),
- :func:`reconstruct_roi` (one known highlight, e.g. a simulated image with known BP and ROI) and
  :func:`reconstruct_rois` (many, their fits batched),
- :func:`detect_specularities`, :func:`extract_isophote`, :func:`fit_ellipse` and the estimators
  in :mod:`simtest.reconstruct.estimators`, for use step by step,
- :func:`write_estimates` / :func:`read_estimates` for ``estimates.json``, :func:`read_frames` /
  :func:`read_table` for a folder's or a video's ``estimates.parquet`` (or ``estimates.jsonl``),
- :class:`ReconSettings`, every setting of the reconstruction in one frozen, validated value.

The function is ``simtest.reconstruct.reconstruct`` (``from simtest.reconstruct import
reconstruct``); ``simtest.reconstruct`` is this package, not a callable.
"""

from __future__ import annotations

from simtest.reconstruct._pixels import Roi, rc_to_uv, uv_to_rc
from simtest.reconstruct.assemble import IsophoteEstimate, SpecularityEstimate
from simtest.reconstruct.detect import Candidate, Detection, detect_specularities
from simtest.reconstruct.estimators import ConeEstimate, estimate_from_conic, joint_cone_axis, select_paper_normal
from simtest.reconstruct.failures import REASONS, Failure
from simtest.reconstruct.fit import EllipseFit, fit_ellipse, fit_ellipses
from simtest.reconstruct.io import SCHEMA_VERSION, read_estimates, write_estimates
from simtest.reconstruct.isophote import Isophote, extract_isophote
from simtest.reconstruct.pipeline import Estimates, reconstruct, reconstruct_roi, reconstruct_rois
from simtest.reconstruct.settings import Normalisation, ReconSettings
from simtest.reconstruct.table import read_frames, read_table

__all__ = ["REASONS", "SCHEMA_VERSION", "Candidate", "ConeEstimate", "Detection", "EllipseFit", "Estimates", "Failure",
           "Isophote", "IsophoteEstimate", "Normalisation", "ReconSettings", "Roi", "SpecularityEstimate",
           "detect_specularities", "estimate_from_conic", "extract_isophote", "fit_ellipse", "fit_ellipses",
           "joint_cone_axis", "rc_to_uv", "read_estimates", "read_frames", "read_table", "reconstruct",
           "reconstruct_roi", "reconstruct_rois", "select_paper_normal", "uv_to_rc", "write_estimates"]

