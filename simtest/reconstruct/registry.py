"""The normal estimators, registered in one place: a name, the function that reads its normal out of
a highlight's estimate, its kind, a line for the reports, and what it gives.

A new estimator is one function and one :func:`register` call; every place that lists estimators
reads them with :func:`names` and :func:`get`. Kinds (:data:`KINDS`): ``oracle`` (N+- closest to
the truth, as the paper reports), ``isophote``, ``baseline`` (the BP ray), ``light_aware``,
``oracle_input`` (a fit on an image a real frame does not give), ``recommendation``.

Examples
--------
>>> from simtest.reconstruct import registry
>>> registry.get("bp_ray").kind
'baseline'
>>> "cone_axis" in registry.names("isophote")
True
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["KINDS", "NORMAL_READERS", "Estimator", "describe", "get", "names", "register", "unit_or_none", "unregister"]

#: The kinds of estimator (module docstring).
KINDS = ("oracle", "isophote", "baseline", "light_aware", "oracle_input", "recommendation")

#: The outputs an estimator may give: a normal, a depth, a stated sigma, a normal per light.
OUTPUTS = ("normal", "depth", "sigma", "light_normals")


@dataclass(frozen=True)
class Estimator:
    """One registered estimator.

    Attributes
    ----------
    name : str
        Its name, the key of its column in every table.
    normal : callable
        ``normal(estimate, truth) -> array_like of shape (3,) or None`` (``truth``: oracles only).
    kind : str
        One of :data:`KINDS`.
    description : str
        One line for the reports.
    outputs : tuple of str
        What it gives, of :data:`OUTPUTS`.
    status_free, default, reference : bool
        Scored whatever the highlight's status (it does not rest on its isophote); scored by a suite
        that lists none; never the best "other" estimator of a report's row.
    rank : int or None
        The recommendation's preference among the light-aware fits (lower first) and among the
        co-located estimators; None: not in that order (rule 5 reads ``rig_centroid`` by name).
    oracle_input : str or None
        For ``oracle_input``: the attribute of the render result it fits.
    """

    name: str
    normal: Callable = field(repr=False)
    kind: str
    description: str
    outputs: tuple = ("normal",)
    status_free: bool = False
    default: bool = False
    reference: bool = False
    rank: int | None = None
    oracle_input: str | None = None


_REGISTRY: dict[str, Estimator] = {}

#: name -> its normal reader, for every registered estimator: the dict the harness scores with
#: (:data:`simtest.harness.estimators.ESTIMATORS`), which a test may patch to plant a bias.
NORMAL_READERS: dict[str, Callable] = {}


def register(name: str, normal: Callable, *, kind: str, description: str, outputs=("normal",),
             status_free: bool = False, default: bool = False, reference: bool = False,
             rank: int | None = None, oracle_input: str | None = None) -> Estimator:
    """Register an estimator (attributes of :class:`Estimator`); a name registered again is
    replaced in place (its order kept).

    Returns
    -------
    Estimator

    Raises
    ------
    ValueError
        A kind not in :data:`KINDS` or an output not in :data:`OUTPUTS`.

    Examples
    --------
    >>> from simtest.reconstruct import registry
    >>> e = registry.register("toy_ray", lambda est, truth: est.bp_ray, kind="baseline",
    ...                       description="the BP ray again", status_free=True)
    >>> registry.names("baseline")
    ('bp_ray', 'toy_ray')
    >>> registry.unregister("toy_ray")
    """
    if kind not in KINDS:
        raise ValueError(f"estimator {name!r}: kind {kind!r} is not one of {', '.join(KINDS)}")
    bad = [o for o in outputs if o not in OUTPUTS]
    if bad:
        raise ValueError(f"estimator {name!r}: outputs {bad} are not among {', '.join(OUTPUTS)}")
    est = Estimator(name, normal, kind, description, tuple(outputs), status_free, default, reference,
                    rank, oracle_input)
    _REGISTRY[name] = est
    NORMAL_READERS[name] = normal
    return est


def unregister(name: str) -> None:
    """Remove an estimator (a test's toy); an unknown name is ignored."""
    _REGISTRY.pop(name, None)
    NORMAL_READERS.pop(name, None)


def get(name: str) -> Estimator:
    """The registered estimator ``name``.

    Raises
    ------
    KeyError
        An unknown name.
    """
    return _REGISTRY[name]


def describe(name: str) -> str:
    """The report line of ``name``, or the name itself where it is not registered."""
    est = _REGISTRY.get(name)
    return name if est is None else est.description


def names(*kinds: str, ranked: bool = False) -> tuple[str, ...]:
    """The registered names, in registration order, of the given kinds (none given: all).

    With ``ranked``, those with a ``rank`` only, by rank (the recommendation's order).
    """
    out = [e for e in _REGISTRY.values() if not kinds or e.kind in kinds]
    if ranked:
        out = sorted((e for e in out if e.rank is not None), key=lambda e: e.rank)
    return tuple(e.name for e in out)


def unit_or_none(v) -> np.ndarray | None:
    """``v`` as a unit vector, or None if it cannot be one.

    Parameters
    ----------
    v : array_like of 3 numbers, None or False
        A direction (any length).

    Returns
    -------
    ndarray of shape (3,) or None
        float64 unit vector; None if ``v`` is None/False, not 3 numbers, non-finite or zero.
    """
    if v is None or v is False:
        return None
    try:
        a = np.asarray(v, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        return None
    n = float(np.linalg.norm(a))
    if not np.isfinite(n) or n == 0.0:
        return None
    return a / n


def _paper_oracle(est, truth) -> np.ndarray | None:
    normals = getattr(est, "normals_paper", None)
    if normals is None or normals is False:
        return None
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    cands = [u for u in (unit_or_none(n) for n in normals) if u is not None]
    if not cands:
        return None
    return max(cands, key=lambda u: float(np.dot(u, truth)))  # closest = largest cosine


def _attr(name: str) -> Callable:
    def get(est, truth):
        return unit_or_none(getattr(est, name, None))

    get.__name__ = f"_{name}"
    return get


def _light_aware(name: str) -> Callable:
    def get(est, truth):
        r = (getattr(est, "light_aware", None) or {}).get(name)
        return None if r is None else unit_or_none(r.normal)

    get.__name__ = f"_{name}"
    return get


def _recommended(est, truth) -> np.ndarray | None:
    rec = getattr(est, "recommended", None)
    return None if rec is None else unit_or_none(rec.normal)


_FIT = ("normal", "depth", "sigma")

register("paper_oracle", _paper_oracle, kind="oracle", default=True, reference=True,
         description="paper, closest of N+ and N- to the truth (oracle, as the paper reports)")
register("paper_selected", _attr("paper_selected"), kind="isophote", default=True, reference=True,
         description="paper, N+ or N- chosen without the truth (the one closer to the BP ray)")
register("cone_axis", _attr("cone_axis"), kind="isophote", default=True, rank=1,
         description="cone axis of C' (unique-sign eigenvector; as dam410/LightModel vanishing_line_paper_co)")
register("joint_cone_axis", _attr("joint_cone_axis"), kind="isophote", default=True, rank=0,
         description="joint cone axis of the nested isophotes")
register("bp_ray", _attr("bp_ray"), kind="baseline", default=True, status_free=True, reference=True, rank=2,
         description="minus the viewing ray of the BP (baseline)")
register("isocurve_fit", _light_aware("isocurve_fit"), kind="light_aware", outputs=_FIT, rank=3,
         description="general isocurve (eq. 2) fitted with the calibrated light (light-aware)")
register("photometric_fit", _light_aware("photometric_fit"), kind="light_aware", outputs=_FIT, status_free=True, rank=0,
         description="ROI intensities fitted with a plane lit by the rig (light-aware)")
register("quadric_fit", _light_aware("quadric_fit"), kind="light_aware", outputs=_FIT + ("light_normals",),
         status_free=True, rank=2,
         description="ROI intensities fitted with a quadric patch lit by the rig (experimental)")
register("cubic_patch_fit", _light_aware("cubic_patch_fit"), kind="light_aware",
         outputs=_FIT + ("light_normals",), status_free=True, rank=1,
         description="ROI intensities fitted with a third-order patch lit by every light of the rig")
register("rig_centroid", _light_aware("rig_centroid"), kind="light_aware", outputs=("normal", "sigma"),
         status_free=True, description="the bisector for the rig's centroid light, where its lobes fuse into one")
register("rig_pair", _light_aware("rig_pair"), kind="light_aware", outputs=_FIT, status_free=True,
         description="the plane two guides' highlights share: fused clipped tops as a stereo pair, or another "
                     "row's plane fit that puts its guide's highlight on this one (rule 0)")
register("recommended", _recommended, kind="recommendation", outputs=_FIT + ("light_normals",), status_free=True,
         reference=True, description="the normal estimates.json recommends (simtest.reconstruct.recommend)")
register("photometric_fit_on_specular", _light_aware("photometric_fit_on_specular"),
         kind="oracle_input", outputs=_FIT, status_free=True, reference=True, oracle_input="specular",
         description="photometric_fit on the renderer's specular image alone (oracle input: no "
                     "diffuse shading, tone curve, noise or clipping; not available on a real frame)")
register("photometric_fit_on_radiance", _light_aware("photometric_fit_on_radiance"),
         kind="oracle_input", outputs=_FIT, status_free=True, reference=True, oracle_input="linear",
         description="photometric_fit on the renderer's linear radiance (oracle input: the diffuse "
                     "shading in; no tone curve, noise or clipping)")
