"""The estimators the harness scores side by side, as a registry of small functions.

Each entry maps a name to ``f(estimate, truth) -> normal (3,) or None``: it reads one normal out of
a :class:`simtest.reconstruct` ``SpecularityEstimate`` (camera frame, unit, facing the camera).
``truth`` is only used by the oracle. Scoring (:func:`score`) turns the normal into an angular
error in degrees against the ground truth (``atan2(|a x b|, a . b)``), or a failure cause.

Estimators (derivations in the Notes of :func:`simtest.geometry.conics.cone_axis` and
:func:`simtest.geometry.conics.circle_pose`):
- ``paper_oracle``: the one of the two circle-pose normals N+- closest to the truth (the paper's
  reporting, an oracle choice).
- ``paper_selected``: the N+- that the reconstruction's non-oracle rule selects.
- ``cone_axis``: eigenvector of C' = K^T C K with the unique-sign eigenvalue (as in the public
  MATLAB code dam410/LightModel, ``vanishing_line_paper_co``).
- ``joint_cone_axis``: one cone axis fitted jointly to nested isophotes at several isovalues.
- ``bp_ray``: minus the unit viewing ray through the detected brightest point (the baseline).
- ``isocurve_fit``, ``photometric_fit``: the light-aware estimators (the general isocurve of eq. 2
  and the photometric plane fit with the calibrated rig, :mod:`simtest.reconstruct.lightaware`),
  scored when the rendered protocol ran them (a rig off the camera centre); ``quadric_fit``, the
  curved-patch fit, run where the photometric fit is not ``ok``, and on every highlight when a
  suite lists it; ``cubic_patch_fit``, the third-order patch fitted to the lobes of every light
  of a rig of several lights, run there too.
- ``recommended``: the normal ``estimates.json`` recommends (:mod:`simtest.reconstruct.recommend`).

The estimators are registered in :mod:`simtest.reconstruct.registry` (a new one is one function
and one registration); :data:`ESTIMATORS` is the registry's dict of readers, a plain dict so that a
test can plant a known bias in one estimator (``monkeypatch.setitem(ESTIMATORS, "cone_axis",
biased)``) and check that the nightly comparison catches it.

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3 (the circle-pose normals N+- of ``paper_oracle`` and ``paper_selected``).
.. [2] D. Forsyth, J. L. Mundy, A. Zisserman, C. Coelho, A. Heller, C. Rothwell, "Invariant
       descriptors for 3-D object recognition and pose", IEEE TPAMI 13(10), 1991 (circle pose).
       https://doi.org/10.1109/34.99233
.. [3] dam410/LightModel, public MATLAB code, branch ``vanishing_line_paper_co`` (prior art of
       the ``cone_axis`` estimator).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from simtest.geometry.angles import angle_between_deg
from simtest.reconstruct.registry import NORMAL_READERS, get, names, unit_or_none

__all__ = ["ESTIMATORS", "LIGHT_AWARE_FITS", "ORACLE_INPUTS", "STATUS_FREE", "score", "unit_or_none"]


#: The light-aware fits of :func:`simtest.reconstruct.light_fits.light_aware_estimates`, each read
#: from a highlight's ``light_aware`` entry of its name.
LIGHT_AWARE_FITS = names("light_aware")

#: name -> f(estimate, truth) -> unit normal or None: the registry's readers
#: (:data:`simtest.reconstruct.registry.NORMAL_READERS`, the same dict).
ESTIMATORS: dict[str, Callable] = NORMAL_READERS
#: The photometric fit on images a real frame does not give (oracle inputs, as paper_oracle is an
#: oracle choice; :func:`simtest.harness.protocols.fit_on_oracle_image`), each with the attribute of
#: the render result it fits: the render's specular radiance alone, and its linear radiance
#: (diffuse shading in; no tone curve, noise or clipping).
ORACLE_INPUTS = {name: get(name).oracle_input for name in names("oracle_input")}

#: Estimators scored whatever the highlight's status (they do not rest on its isophote: the BP
#: ray, and the photometric fit and the recommendation, which take a merged highlight too).
STATUS_FREE = tuple(name for name in names() if get(name).status_free)


def _cause(est, name: str) -> str:
    status = getattr(est, "status", None)
    if status is not None and status != "ok":
        return str(status)
    if get(name).kind in ("light_aware", "oracle_input"):
        r = (getattr(est, "light_aware", None) or {}).get(name)
        return f"{name}_not_run" if r is None else str(r.status)
    if name == "joint_cone_axis":
        isos = getattr(est, "isophotes", ()) or ()
        n_ok = sum(1 for i in isos if getattr(i, "status", None) == "ok")
        return "joint_fewer_than_2_isophotes" if n_ok < 2 else "joint_failed"
    return f"no_{name}"


def _light_normal(est, name: str, light: int) -> np.ndarray | None:
    """The normal of ``name`` at the specular point of light ``light``, where the estimator gives
    one per light (``light_normals``), else None."""
    if get(name).kind == "recommendation":
        r = getattr(est, "recommended", None)
    else:
        r = (getattr(est, "light_aware", None) or {}).get(name)
    ln = getattr(r, "light_normals", None) if r is not None else None
    if ln is None:
        return None
    ln = np.asarray(ln, dtype=np.float64).reshape(-1, 3)
    return unit_or_none(ln[light]) if 0 <= light < len(ln) else None


def score(est, truth, names, light: int | None = None) -> dict[str, tuple[float, str | None]]:
    """Angular error of each estimator on one estimate.

    Parameters
    ----------
    est : SpecularityEstimate or None
        None when no specularity was found (every estimator fails with ``"not_detected"``).
        An estimate whose status is not ``"ok"`` fails every estimator but ``bp_ray`` with
        that status as the cause.
    truth : array_like of shape (3,)
        Ground-truth normal, OpenCV camera frame (any length; it is normalised).
    names : iterable of str
        Estimators to score (keys of :data:`ESTIMATORS`).
    light : int, optional
        The index in the rig of the light whose highlight ``truth`` belongs to. An estimator that
        gives a normal per light (``light_normals``:
        :func:`~simtest.reconstruct.lightaware.cubic_patch_fit` and a recommendation drawn from
        it) is scored with that light's normal; the others with their one normal.

    Returns
    -------
    dict
        name -> ``(error_deg, None)`` or ``(nan, cause)``; the error is
        ``atan2(|n x truth|, n . truth)`` in degrees, in [0, 180].

    Raises
    ------
    KeyError
        If a name is not in :data:`ESTIMATORS`.
    """

    truth = unit_or_none(truth)
    out: dict[str, tuple[float, str | None]] = {}
    for name in names:
        if est is None:
            out[name] = (float("nan"), "not_detected")
            continue
        if truth is None:
            out[name] = (float("nan"), "no_ground_truth")
            continue
        status = getattr(est, "status", "ok")
        if not get(name).status_free and status is not None and status != "ok":
            # The reconstruction flagged this highlight (merged, cut contour, ...): its isophote
            # normals are not used, as a user of the pipeline would not use them.
            out[name] = (float("nan"), str(status))
            continue
        n = _light_normal(est, name, light) if light is not None else None
        if n is None:
            n = unit_or_none(ESTIMATORS[name](est, truth))
        if n is None:
            out[name] = (float("nan"), _cause(est, name))
        else:
            out[name] = (float(angle_between_deg(n, truth)), None)
    return out
