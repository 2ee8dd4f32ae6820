"""The estimators the harness scores side by side: one normal read out of each estimate.

``f(estimate, truth) -> normal (3,) or None`` per name (camera frame, facing the camera; ``truth``
is read by the oracle only), registered in :mod:`simtest.reconstruct.registry`. :func:`score`
turns each normal into an angular error in degrees against the ground truth, or a failure cause.
``paper_oracle``: the circle-pose normal N+- nearest the truth [1]_ [2]_; ``paper_selected``: the
one the non-oracle rule selects; ``cone_axis``: the eigenvector of C' = K^T C K with the
unique-sign eigenvalue [3]_; ``joint_cone_axis``: one axis fitted to nested isophotes; ``bp_ray``:
minus the viewing ray through the BP (the baseline); the light-aware fits
(:mod:`simtest.reconstruct.lightaware`); ``recommended``: the normal ``estimates.json``
recommends. :data:`ESTIMATORS` is a plain dict so that a test can plant a bias in one.

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3.
.. [2] D. Forsyth, J. L. Mundy, A. Zisserman, C. Coelho, A. Heller, C. Rothwell, "Invariant
       descriptors for 3-D object recognition and pose", IEEE TPAMI 13(10), 1991.
       https://doi.org/10.1109/34.99233
.. [3] dam410/LightModel, public MATLAB code, branch ``vanishing_line_paper_co``.
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
#: The photometric fit on oracle images no real frame gives, each with the render result's attribute
#: it fits (:func:`simtest.harness.protocols.fit_on_oracle_image`).
ORACLE_INPUTS = {name: get(name).oracle_input for name in names("oracle_input")}

#: Estimators scored whatever the highlight's status (they do not rest on its isophote).
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
    """The normal of ``name`` at light ``light``'s specular point where it gives one per light, else None."""
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
        None: every estimator fails with ``"not_detected"``. A status other than ``"ok"`` fails
        every estimator that is not status-free, with that status as the cause.
    truth : array_like of shape (3,)
        Ground-truth normal, OpenCV camera frame (normalised here).
    names : iterable of str
        Estimators to score (keys of :data:`ESTIMATORS`).
    light : int, optional
        The rig index of the light whose highlight ``truth`` belongs to: an estimator with
        ``light_normals`` is scored with that light's normal.

    Returns
    -------
    dict
        name -> ``(error_deg, None)`` or ``(nan, cause)``; the error ``atan2(|n x truth|, n . truth)``
        in degrees.

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
            # a flagged highlight's isophote normals are not used, as a user would not use them
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
