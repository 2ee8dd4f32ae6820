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

A frame's path through the modules, in order (:func:`reconstruct` in ``pipeline``; ``frame_pass`` is one
pass of the middle stages):

1. ``frame_prep``: the frame as the stages see it (camera model, rays, luma, noise, smoothing).
2. ``detect`` (pixels: ``detect_pixels``; the candidates' table: ``candidates``): bright components, each
   candidate's BP and ROI, or why it is not fitted (``failures.REASONS``).
3. ``frame_verify`` (early): the BP checks that need no isophote (``not_specular`` candidates are not contoured).
4. ``isophotes`` (one ROI: ``isophote``; contours of a whole frame: ``marching``), then ``fit`` (the ellipse)
   and ``assemble`` (``cone_fit``, ``estimators``): per isophote its point conic C, cone axis and circle
   pose; per highlight a :class:`SpecularityEstimate`.
5. ``frame_verify`` and ``verify`` (pixels: ``evidence_pixels``): the specularity checks, the status and the
   confidence; ``broad_lobes`` runs 2 to 5 again on a wider background square where a lobe needs it.
6. With a camera file's light rig (the CLI, ``rig_centroid.light_aware_with_rig``): ``light_fits`` runs the
   light-aware estimators of ``lightaware`` on the ok highlights; ``rig_lobes`` gives fused guides' lobes
   a row each (and a row left with the BP ray the plane that places it), ``rig_pairs`` says where the other
   guides' highlights lie, ``rig_centroid`` fits fused lobes by their centroid, ``curved_lobes`` a curved
   patch's lobes, which the plane's checks reject, by one patch fit; ``lone_lobes`` confirms a weak lobe whose
   twin lies outside the frame; ``recommend`` picks each highlight's normal.
7. ``result`` (``Reconstruction``, what :func:`reconstruct` returns, and its tables), written by ``io`` (``estimates.json``),
   ``table`` (Parquet), ``overlay`` and ``view3d``; ``frames`` runs folders and videos, ``cli`` the command.

Every decision number the stages apply is in :mod:`simtest.decisions`; every estimator's name in ``registry``.
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

