"""``estimates.json``: the versioned file format of reconstruction results.

Written by :func:`write_estimates` (orjson, indented two spaces), read back by
:func:`read_estimates` (schemas 1 and 2). The schema is ``docs/estimates-format.md``; a change
that removes or re-interprets a field bumps :data:`SCHEMA_VERSION`, adding one does not. Frames
go to ``estimates.parquet`` or ``estimates.jsonl`` (:mod:`simtest.reconstruct.table`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import orjson as _orjson

from simtest._io import atomic_write_bytes
from simtest._version import __version__
from simtest.reconstruct.registry import names

SCHEMA_VERSION = 2
#: The light-aware estimators whose normals ``normals`` carries (schema 2).
LIGHT_AWARE_NORMALS = names("light_aware")
#: The schemas :func:`read_estimates` reads.
READABLE_SCHEMAS = (1, 2)

CONVENTIONS = {
    "frame": "OpenCV camera frame: x right, y down, z forward",
    "normals": "unit vectors in the camera frame facing the camera (n . ray < 0)",
    "pixels": "(u, v) = (column, row), pixel centres at integer coordinates",
    "angles": "degrees",
    "depths": "depth_mm: distance from the camera centre to the surface along the BP's viewing ray, mm (a range, "
              "not a z-depth); point_mm: that point, camera frame, mm, whose z is the z-depth of ground_truth.npz "
              "and highlights.json",
}

_REQUIRED_TOP = ("schema", "simtest_version", "image", "K", "dist_coeffs", "isovalues", "specularities")
_REQUIRED_SPEC = ("bp_px", "status", "normals", "ellipse", "conic", "fit_residual_px", "eigenvalue_gap")


def _vec(x):
    # tolist: the same Python floats as float() of each element, in one call
    return None if x is None else np.asarray(x, dtype=np.float64).ravel().tolist()


def _mat(x):
    return None if x is None else np.asarray(x, dtype=np.float64).tolist()  # (rows, columns)


def _num(x):
    return None if x is None else float(x)


def _ellipse(e):
    if e is None:
        return None
    return {"center_px": _vec(e.center), "semi_axes_px": _vec(e.semi_axes), "angle_deg": float(np.degrees(e.angle_rad))}


def _isophote_dict(iso, include_points: bool) -> dict:
    d = {
        "isovalue": float(iso.isovalue),
        "status": iso.status,
        "detail": iso.detail,
        "closed": bool(iso.closed),
        "n_points": 0 if iso.points_uv is None else int(len(iso.points_uv)),
        "ellipse": _ellipse(iso.ellipse),
        "conic": _mat(iso.conic),
        "fit_residual_px": _num(iso.fit_residual_px),
        "eigenvalue_gap": _num(iso.eigenvalue_gap),
        "normals": {
            "paper": _mat(iso.normals_paper),
            "paper_selected": _vec(iso.paper_selected),
            "paper_selected_index": iso.paper_selected_index,
            "cone_axis": _vec(iso.cone_axis),
        },
    }
    if include_points and iso.points_uv is not None:
        d["points_px"] = _mat(iso.points_uv)
    return d


def _rows(a):
    """(J, 3) unit vectors as lists, a row that is not finite as null; null for None."""
    if a is None:
        return None
    return [_vec(r) if np.all(np.isfinite(r)) else None for r in np.asarray(a, dtype=np.float64).reshape(-1, 3)]


def _nums(a):
    """(J,) numbers as a list (NaN as null); null for None."""
    return None if a is None else [float(v) if np.isfinite(v) else None
                                   for v in np.asarray(a, dtype=np.float64).reshape(-1)]


def _point_mm(depth_mm, bp_ray) -> list | None:
    """The point ``depth_mm`` (a range, mm) along the BP's viewing ray ``-bp_ray``, camera frame, mm;
    its z is the z-depth a depth map holds. None without a depth."""
    if depth_mm is None or bp_ray is None:
        return None
    return (-float(depth_mm) * np.asarray(bp_ray, dtype=np.float64).ravel()).tolist()


def _light_aware_dict(la: dict) -> dict:
    """The ``light_aware`` block of a specularity: each light-aware result's fields, JSON-ready."""
    return {name: {"status": r.status, "detail": r.detail, "depth_mm": _num(r.depth_mm),
                   "normal_sigma_deg": _num(r.normal_sigma_deg), "depth_sigma_mm": _num(r.depth_sigma_mm),
                   "distance_mm": _num(r.distance_mm), "roughness": _num(r.roughness),
                   "lobe": getattr(r, "lobe", None), "projection": getattr(r, "projection", None),
                   "light_normals": _rows(r.light_normals),
                   "light_depths_mm": _nums(r.light_depths_mm),
                   "light_normal_sigmas_deg": _nums(r.light_normal_sigmas_deg),
                   "depth_range_mm": _nums(r.depth_range_mm)}
            for name, r in la.items()}


def estimate_to_dict(est, include_points: bool = False) -> dict:
    """One :class:`~simtest.reconstruct.assemble.SpecularityEstimate` as a schema-2 dict.

    Parameters
    ----------
    est : SpecularityEstimate
        One estimate.
    include_points : bool
        Also write each isophote's contour points (``points_px``, (N, 2) lists).

    Returns
    -------
    dict
        JSON-ready (no NaN: missing values are None): ``bp_px`` [u, v], ``bp_intensity``,
        ``saturated``, ``roi`` [row0, row1, col0, col1], ``status``, ``detail``, ``normals``
        (``paper`` 2 x 3, ``paper_selected``, ``paper_selected_index``, ``cone_axis``,
        ``joint_cone_axis``, ``bp_ray``: unit, OpenCV camera frame, facing the camera),
        ``ellipse`` (px, degrees), ``conic`` (3 x 3), ``fit_residual_px``, ``eigenvalue_gap`` and
        ``isophotes``.
    """
    p = est.primary
    sel_idx = None if p is None else p.paper_selected_index
    rec = est.recommended
    la = getattr(est, "light_aware", None) or {}
    return {
        "normal": _vec(rec.normal),
        "normal_from": rec.normal_from,
        "depth_mm": _num(rec.depth_mm),
        "point_mm": _point_mm(rec.depth_mm, est.bp_ray),
        "normal_sigma_deg": _num(rec.normal_sigma_deg),
        "light_normals": _rows(getattr(rec, "light_normals", None)),
        "light_depths_mm": _nums(getattr(rec, "light_depths_mm", None)),
        "light_aware": _light_aware_dict(la),
        "bp_px": _vec(est.bp_px),
        "bp_intensity": float(est.bp_intensity),
        "saturated": bool(est.saturated),
        "roi": [int(v) for v in est.roi],
        "status": est.status,
        "detail": est.detail,
        "confidence": _num(getattr(est, "confidence", None)),
        "normals": {
            "paper": _mat(est.normals_paper),
            "paper_selected": _vec(est.paper_selected),
            "paper_selected_index": sel_idx,
            "cone_axis": _vec(est.cone_axis),
            "joint_cone_axis": _vec(est.joint_cone_axis),
            "bp_ray": _vec(est.bp_ray),
            **{name: _vec(la[name].normal) if name in la else None for name in LIGHT_AWARE_NORMALS},
        },
        "ellipse": _ellipse(est.ellipse),
        "conic": _mat(est.conic),
        "fit_residual_px": _num(est.fit_residual_px),
        "eigenvalue_gap": _num(est.eigenvalue_gap),
        "isophotes": [_isophote_dict(i, include_points) for i in est.isophotes],
    }


# JSON: the document as dicts and lists, its text written by orjson


def _not_finite_at(obj, where: str):
    """The path of the first number in ``obj`` that is not finite, or None."""
    t = type(obj)
    if t is dict or t is list or t is tuple:
        for k, v in obj.items() if t is dict else enumerate(obj):
            if type(v) in _SCALARS_OK:
                continue
            bad = _not_finite_at(v, (f"{where}.{k}" if where else str(k)) if t is dict else f"{where}[{k}]")
            if bad is not None:
                return bad
        return None
    if isinstance(obj, float | np.floating):
        return None if math.isfinite(obj) else f"{where} = {float(obj)!r}"
    if isinstance(obj, np.ndarray) and obj.dtype.kind in "fc" and not np.all(np.isfinite(obj)):
        return f"{where} (an array with values that are not finite)"
    return None


#: Types that need no look inside (a float is looked at: it may be NaN).
_SCALARS_OK = frozenset({str, int, bool, type(None)})
#: orjson's options: numpy arrays and scalars as their numbers (float64 written to round-trip).
_ORJSON_OPTIONS = _orjson.OPT_SERIALIZE_NUMPY


def dumps(obj, *, indent: bool = False) -> bytes:
    """``obj`` as JSON bytes (UTF-8), written by orjson; NaN and infinity refused.

    Parameters
    ----------
    obj : dict or list
        Made of dicts with str keys, lists, tuples, str, int, float, bool, None and numpy arrays
        or scalars.
    indent : bool
        Two spaces per level and a final newline (``estimates.json``); else one compact line
        without a newline (a line of ``estimates.jsonl``).

    Returns
    -------
    bytes
        The JSON text. Numbers are written to round-trip (the shortest digits that read back as
        the same float64).

    Raises
    ------
    ValueError
        Naming the first value that is not finite (its key path): JSON has no NaN, and a missing
        value is written as None by the caller, never left as NaN.
    """
    bad = _not_finite_at(obj, "")
    if bad is not None:
        raise ValueError(f"value not finite, JSON has no NaN or infinity: {bad}")
    if indent:
        return _orjson.dumps(obj, option=_ORJSON_OPTIONS | _orjson.OPT_INDENT_2) + b"\n"
    return _orjson.dumps(obj, option=_ORJSON_OPTIONS)


def estimates_document(estimates, *, K, image=None, image_shape=None, dist_coeffs=None, isovalues=(), normalise="bp",
                       include_points=False, camera=None, lights=None, detection=None) -> dict:
    """The whole schema-2 document as a dict (``docs/estimates-format.md``).

    Parameters
    ----------
    estimates : list of SpecularityEstimate
        From :func:`~simtest.reconstruct.pipeline.reconstruct`.
    K : array_like of shape (3, 3) or None
        Pinhole intrinsics used, px (None for a fisheye or omnidirectional camera).
    image : str or Path, optional
        The image file, recorded as text.
    image_shape : tuple of int, optional
        ``(H, W, ...)``; the first two are recorded.
    dist_coeffs : array_like, optional
        OpenCV distortion coefficients used.
    isovalues : sequence of float
        The isovalues t in (0, 1).
    normalise : str
        ``"bp"`` or ``"full_scale"``.
    include_points : bool
        Also write the contour points.
    camera : CameraModel, optional
        The camera model used (its camera-file object).
    lights : LightRig, optional
        The light rig the light-aware estimators used.
    detection : dict, optional
        What detection examined (:meth:`~simtest.reconstruct.result.Reconstruction.detection_record`);
        default the record ``estimates`` carries, if any, else null.

    Returns
    -------
    dict
    """
    if detection is None and hasattr(estimates, "detection_record"):
        detection = estimates.detection_record()
    return {
        "schema": SCHEMA_VERSION,
        "simtest_version": __version__,
        "image": None if image is None else str(image),
        "image_shape": None if image_shape is None else [int(v) for v in image_shape[:2]],
        "K": _mat(K),
        "dist_coeffs": _vec(dist_coeffs),
        "camera": None if camera is None else camera.to_json_dict(),
        "isovalues": [float(t) for t in isovalues],
        "normalise": normalise,
        "conventions": CONVENTIONS,
        "lights": None if lights is None else [
            {"position_mm": [float(v) for v in lt.position_mm], "intensity": float(lt.intensity),
             "falloff": lt.falloff, "profile_exponent": float(lt.profile_exponent)}
            for lt in lights.lights],
        "detection": detection,
        "specularities": [estimate_to_dict(e, include_points) for e in estimates],
    }


def write_estimates(path, estimates, *, K, image=None, image_shape=None, dist_coeffs=None, isovalues=(), normalise="bp",
                    include_points=False, camera=None, lights=None) -> Path:
    """Write ``estimates.json`` atomically (temporary file in the same folder, then os.replace).

    Parameters
    ----------
    path : str or Path
        Destination file.
    estimates : list of SpecularityEstimate
        From :func:`~simtest.reconstruct.pipeline.reconstruct`.
    K : array_like of shape (3, 3)
        Intrinsics used.
    image, image_shape, dist_coeffs, isovalues, normalise, camera, lights : optional
        Recorded as given (:func:`estimates_document`).
    include_points : bool
        Also write each isophote's contour points.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ValueError
        Naming a value that is not finite (:func:`dumps`); nothing is written.
    OSError
        If the folder is not writable.
    """
    doc = estimates_document(estimates, K=K, image=image, image_shape=image_shape,
                             dist_coeffs=dist_coeffs, isovalues=isovalues, normalise=normalise,
                             include_points=include_points, camera=camera, lights=lights)
    return atomic_write_bytes(path, dumps(doc, indent=True))


def read_estimates(path) -> dict:
    """Read and check an ``estimates.json`` file.

    Parameters
    ----------
    path : str or Path
        The file written by :func:`write_estimates`.

    Returns
    -------
    dict
        The document (schema 1 or 2, as written), with ``K`` as a (3, 3) ndarray.

    Raises
    ------
    ValueError
        Naming the file and the key: unreadable JSON, unknown schema, a missing key.
    """
    path = Path(path)
    try:
        doc = _orjson.loads(path.read_bytes())
    except (OSError, _orjson.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read estimates JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: top level is not a JSON object")
    if doc.get("schema") not in READABLE_SCHEMAS:
        raise ValueError(f"{path}: key 'schema' is {doc.get('schema')!r}, expected one of {READABLE_SCHEMAS}")
    for key in _REQUIRED_TOP:
        if key not in doc:
            raise ValueError(f"{path}: missing key {key!r}")
    for i, spec in enumerate(doc["specularities"]):
        for key in _REQUIRED_SPEC:
            if key not in spec:
                raise ValueError(f"{path}: specularities[{i}] is missing key {key!r}")
    doc["K"] = None if doc["K"] is None else np.asarray(doc["K"], dtype=np.float64)
    return doc


#: What ``simtest reconstruct`` writes in its ``--out`` folder (and nothing else may be there).
RECONSTRUCT_FILES = ("estimates.json", "overlay.png", "view.png", "estimates.parquet", "estimates.jsonl")
