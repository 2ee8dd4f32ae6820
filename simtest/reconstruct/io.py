"""``estimates.json``: the versioned file format of reconstruction results.

Written by ``simtest reconstruct`` and :func:`write_estimates`; read back by
:func:`read_estimates`. Other tools (harness, notebooks) read it; the schema below is a contract.
A change that removes or re-interprets a field bumps ``schema``; adding a field does not.

Schema 2
--------
Schema 2 is schema 1 plus, per specularity, the normal recommended to a user and the light-aware
estimators (:mod:`simtest.reconstruct.recommend`, whose docstring states the recommendation rule)::

    "normal": [x, y, z],               # the recommended normal (never null: bp_ray at worst)
    "normal_from": "photometric_fit" | "cubic_patch_fit" | "quadric_fit" | "isocurve_fit"
                   | "joint_cone_axis" | "cone_axis" | "bp_ray",
    "depth_mm": float or null,         # depth of the specular point along its ray, mm; null when
                                       # not observable (no rig, a co-located one, epsilon/d small)
    "normal_sigma_deg": float or null, # 1-sigma angle of the recommended normal, degrees
    "normals": {..., "isocurve_fit": [x, y, z] or null, "photometric_fit": [x, y, z] or null,
                "quadric_fit": [x, y, z] or null, "cubic_patch_fit": [x, y, z] or null},
                                       # each light-aware estimator's normal (null: not run or
                                       # no normal); quadric_fit and cubic_patch_fit were added
                                       # later in schema 2 (absent from older files)
    "light_normals": [[x, y, z], ...] or null,  # the recommended estimator's normal at each
                                       # light's specular point (cubic_patch_fit), rig order
    "light_depths_mm": [float, ...] or null,   # the depth of each light's specular point, mm
    "light_aware": {name: {"status": str, "detail": str, "depth_mm": float or null,
                           "normal_sigma_deg": float or null, "depth_sigma_mm": float or null,
                           "distance_mm": float or null, "roughness": float or null,
                           "lobe": "phong" | "ggx" | null,   # photometric_fit's lobe
                           "projection": "body_colours" | "least_fluctuation" |
                                         "darkest_channel" | null,  # photometric_fit on RGB:
                                       # the single image fitted (null: one channel)
                           "light_normals": [[x, y, z], ...] or null,
                           "light_depths_mm": [float, ...] or null,
                           "light_normal_sigmas_deg": [float, ...] or null,  # 1-sigma of each
                                       # of light_normals, degrees (cubic_patch_fit)
                           "depth_range_mm": [near, far] or null}}  # one-light quadric_fit:
                                       # the depths the data cannot exclude, mm (depth_mm null)

and at the top level ``"lights"``: the rig used (the camera file's list), or null, and
``"detection"``: ``{"components": bright components found, "examined": those with an entry in
``specularities``, "not_examined": those left out by the cap, "max_candidates": the cap or null}``
(null in files written before it). Every field of schema 1 keeps its meaning; :func:`read_estimates`
reads both.

Schema 1
--------
Conventions for every field: camera frame OpenCV (x right, y down, z forward); normals are unit
3-vectors in that frame facing the camera (n . ray < 0); pixels (u, v) = (column, row) with pixel
centres at integer coordinates; angles in degrees; ``null`` where a value does not exist (a failed
step), never NaN.

.. code-block:: text

    {
      "schema": 1,                       # int, this format's version
      "simtest_version": "0.1.0",        # str, package version that wrote the file
      "image": "path/to/image.png",      # str or null, the image as given
      "image_shape": [H, W],             # [int, int]
      "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] or null,   # pinhole K; null for other models
      "dist_coeffs": [k1, k2, p1, p2, k3] or null,   # OpenCV order; points undistorted if given
      "camera": {"model": ..., ...} or null,   # the camera file's model object (optional field)
      "isovalues": [t1, t2, ...],        # each in (0, 1); t1 is the primary isovalue
      "normalise": "bp",                 # "bp": t relative to the BP intensity; "full_scale"; or
                                         # "local": relative to the BP above the ROI-border median
      "conventions": {...},              # the conventions above, as text
      "specularities": [                 # one per candidate highlight, brightest first
        {
          "bp_px": [u, v],               # brightest point as detected (distorted image), px
          "bp_intensity": float,         # normalising intensity, image units
          "saturated": bool,             # BP is the centroid of a clipped plateau
          "roi": [row0, row1, col0, col1],   # array indices, half-open
          "status": "ok" | reason,       # reason: a key of simtest.reconstruct.failures.REASONS
          "detail": str,                 # numbers behind a failure ("" when ok)
          "normals": {
            "paper": [[x, y, z], [x, y, z]] or null,   # N+ and N- (circle pose), primary
            "paper_selected": [x, y, z] or null,       # non-oracle choice: closer to bp_ray
            "paper_selected_index": 0 | 1 | null,      # 0: N+, 1: N-
            "cone_axis": [x, y, z] or null,            # primary cone axis
            "joint_cone_axis": [x, y, z] or null,      # nested isophotes (>= 2 succeeded)
            "bp_ray": [x, y, z]                        # minus the unit ray through the BP
          },
          "ellipse": {"center_px": [u, v], "semi_axes_px": [a, b], "angle_deg": float} or null,
          "conic": [[...], [...], [...]] or null,      # point conic, undistorted px, |C|_F = 1
                                                       # (null for fisheye/omnidirectional models)
          "fit_residual_px": float or null,            # RMS Sampson distance
          "eigenvalue_gap": float or null,             # 0 for a right circular cone
          "isophotes": [                 # one per isovalue, same order as "isovalues"
            {"isovalue": t, "status": ..., "detail": ..., "closed": bool, "n_points": int,
             "ellipse": ..., "conic": ..., "fit_residual_px": ..., "eigenvalue_gap": ...,
             "normals": {"paper": ..., "paper_selected": ..., "cone_axis": ...},
             "points_px": [[u, v], ...]}      # only when written with include_points=True
          ]
        }
      ]
    }

The status and every normal of a specularity are those of its primary isophote (the first
isovalue), except ``status == "merged"`` (the primary isophote encloses another highlight's BP) and
detection rejections (``too_small``, ``touches_border``, ``not_elliptical``, ``merged``), which
have an empty ``isophotes`` list and null normals except ``bp_ray``.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import orjson as _orjson  # a float64 array's JSON text in C: estimates.jsonl's cost on a video

from simtest._io import atomic_write_json
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
    return {
        "center_px": _vec(e.center),
        "semi_axes_px": _vec(e.semi_axes),
        "angle_deg": float(np.degrees(e.angle_rad)),
    }


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
    return [_vec(r) if np.all(np.isfinite(r)) else None
            for r in np.asarray(a, dtype=np.float64).reshape(-1, 3)]


def _nums(a):
    """(J,) numbers as a list (NaN as null); null for None."""
    return None if a is None else [float(v) if np.isfinite(v) else None
                                   for v in np.asarray(a, dtype=np.float64).reshape(-1)]


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
    """One :class:`~simtest.reconstruct.pipeline.SpecularityEstimate` as a schema-2 dict.

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


# ------------------------------------------------------------------------------------------------
# the same JSON text, written directly (a video's estimates.jsonl: thousands of estimates a frame)

#: json.dumps' string writer (``ensure_ascii``: the default), quotes included.
_jstr = json.encoder.encode_basestring_ascii
#: The compact writer of estimates.jsonl, for the parts written as dicts (light-aware results).
_json = json.JSONEncoder(allow_nan=False, separators=(",", ":")).encode
#: orjson's option for numpy arrays (:func:`_atxt`).
_ORJSON_NUMPY = _orjson.OPT_SERIALIZE_NUMPY


def _orjson_is_repr(t: str) -> bool:
    """Whether orjson's text ``t`` of finite floats is the one json.dumps writes (float.__repr__):
    it differs only in the notation of |x| < 1e-4 (positional: "0.0000...", or an exponent without
    its sign's padding, "1e-7") and of |x| >= 1e16 (its exponent, "1e16"), and writes NaN and inf
    as null ("n"); a text with none of these (or with ".0000" inside a number, harmlessly
    refused) is repr's."""
    return "e" not in t and "n" not in t and ".0000" not in t


#: orjson's exponent of two digits or more after the padding :func:`_as_repr` adds to every one
_EXP_LONG = re.compile(r"e-0(?=\d\d)")
#: orjson's positional text of 1e-5 <= |x| < 1e-4 (its only positional |x| < 1e-4): "0.0000" and
#: the digits (at the start of a number: :func:`_exp5` checks; a look-behind here would make
#: the search ten times slower)
_POSITIONAL = re.compile(r"0\.0000([1-9])(\d*)")


def _exp5(m) -> str:
    i = m.start()
    if i and m.string[i - 1] in "0123456789.":  # inside a number, as 10.00001: repr's already
        return m.group(0)
    rest = m.group(2)
    return f"{m.group(1)}.{rest}e-05" if rest else f"{m.group(1)}e-05"


def _as_repr(t: str) -> str | None:
    """orjson's text of float64s (an array's or a list's) as json.dumps writes them (repr's
    notation): its shortest round-trip digits are repr's, only the notation differs; orjson writes
    an exponent bare ("1e-7", "1.5e16": repr "1e-07", "1.5e+16"; orjson 3.10 and later write
    "1.5e+16", which is first made bare) and 1e-5 <= |x| < 1e-4 positionally ("0.0000123": repr
    "1.23e-05"). None where a value is not finite (orjson's null). A text of numbers only (no
    strings), so every "e" is an exponent (``tests/test_io_fast.py`` compares it with repr over
    the whole float64 range)."""
    if "n" in t:
        return None
    if "e" in t:  # every exponent signed, at least two digits: "e-7" -> "e-07", "e16" -> "e+16"
        t = t.replace("e+", "e")  # orjson's own sign, where its version writes one
        t = _EXP_LONG.sub("e-", t.replace("e-", "E").replace("e", "e+").replace("E", "e-0"))
    if ".0000" in t:
        t = _POSITIONAL.sub(_exp5, t)
    return t


#: np.degrees is x * (180 / pi) in float64 (the same bits for a Python float).
_DEG = 180.0 / np.pi


def _json_or_null(x) -> str:
    return "null" if x is None else _json(x)


def _not_finite(text: str) -> ValueError:
    return ValueError(f"Out of range float values are not JSON compliant: {text}")


def _ftxt(x) -> str:
    """``float(x)`` as json.dumps writes it (float.__repr__), ``null`` for None."""
    if x is None:
        return "null"
    t = _orjson.dumps(float(x)).decode()  # as _atxt: orjson's text in repr's notation
    if _orjson_is_repr(t):
        return t
    t = repr(float(x))
    if "n" in t:  # nan, inf, -inf: json.dumps(allow_nan=False) refuses them too
        raise _not_finite(t)
    return t


def _atxt(x, flat: bool) -> str:
    """An array as json.dumps writes its float64 ``tolist()`` (flattened if ``flat``); ``null``
    for None. A list's repr of finite floats differs from compact JSON only by its spaces."""
    if x is None:
        return "null"
    if type(x) is np.ndarray and x.dtype.char == "d" and (x.ndim == 1 or not flat):
        if x.ndim <= 2 and x.flags.c_contiguous:
            # orjson's shortest round-trip digits are float.__repr__'s, in repr's notation
            # (_as_repr); an array that is not finite takes repr's path (tests/test_io_fast.py)
            t = _as_repr(_orjson.dumps(x, option=_ORJSON_NUMPY).decode())
            if t is not None:
                return t
        t = repr(x.tolist())  # float64 already: skip the conversions (the same Python floats)
    else:
        a = np.asarray(x, dtype=np.float64)
        t = repr((a.ravel() if flat else a).tolist())
    t = t.replace(" ", "")
    if "n" in t:
        raise _not_finite(t)
    return t


def _ellipse_txt(e) -> str:
    if e is None:
        return "null"
    return (f'{{"center_px":{_atxt(e.center, True)},"semi_axes_px":{_atxt(e.semi_axes, True)},'
            f'"angle_deg":{_ftxt(float(e.angle_rad) * _DEG)}}}')


def _int_txt(x) -> str:
    # an int (or None) as json.dumps writes it; anything else goes through json (which raises)
    return "null" if x is None else repr(x) if type(x) is int else _json(x)


def _isophote_json(iso, include_points: bool):
    """The text of :func:`_isophote_dict` and the texts of the parts a specularity repeats from
    its primary isophote: (ellipse, conic, fit_residual_px, eigenvalue_gap, paper,
    paper_selected, paper_selected_index, cone_axis)."""
    parts = (_ellipse_txt(iso.ellipse), _atxt(iso.conic, False), _ftxt(iso.fit_residual_px),
             _ftxt(iso.eigenvalue_gap), _atxt(iso.normals_paper, False), _atxt(iso.paper_selected, True),
             _int_txt(iso.paper_selected_index), _atxt(iso.cone_axis, True))
    return _isophote_text(iso, _ftxt(iso.isovalue), parts, include_points), parts


def _isophote_text(iso, isovalue: str, parts: tuple, include_points: bool) -> str:
    """The text of :func:`_isophote_dict` from the isovalue's text and the texts of its parts
    (:func:`_isophote_json`'s), one isophote at a time or a frame's at once alike."""
    n_points = 0 if iso.points_uv is None else int(len(iso.points_uv))
    text = (f'{{"isovalue":{isovalue},"status":{_jstr(iso.status)},"detail":{_jstr(iso.detail)},'
            f'"closed":{"true" if iso.closed else "false"},"n_points":{n_points},"ellipse":{parts[0]},'
            f'"conic":{parts[1]},"fit_residual_px":{parts[2]},"eigenvalue_gap":{parts[3]},'
            f'"normals":{{"paper":{parts[4]},"paper_selected":{parts[5]},"paper_selected_index":{parts[6]},'
            f'"cone_axis":{parts[7]}}}')
    if include_points and iso.points_uv is not None:
        text += f',"points_px":{_atxt(iso.points_uv, False)}'
    return text + "}"


def _roi_txt(roi) -> str:
    # [int(v) for v in roi] as json writes it ("%d" truncates as int() does)
    return "[%d,%d,%d,%d]" % tuple(roi) if len(roi) == 4 else _json([int(v) for v in roi])


_NO_PRIMARY = ("null",) * 8
_NO_LIGHT_AWARE_NORMALS = ",".join(f'"{name}":null' for name in LIGHT_AWARE_NORMALS)


def estimate_json(est, include_points: bool = False) -> str:
    """:func:`estimate_to_dict` as the compact JSON text estimates.jsonl holds, written directly.

    The same text as ``json.dumps(estimate_to_dict(est, include_points), allow_nan=False,
    separators=(",", ":"))``, character for character, at a fraction of its cost: no dicts, each
    float formatted once where the dict repeats it (the primary isophote's fit at the top level,
    the recommended normal), and a short path for a rejected candidate (no isophotes, no
    light-aware results).

    Parameters
    ----------
    est : SpecularityEstimate
        One estimate.
    include_points : bool
        Also write each isophote's contour points.

    Returns
    -------
    str
        One JSON object, no whitespace.

    Raises
    ------
    ValueError
        If a value is not finite (as json.dumps with ``allow_nan=False``).
    """
    la = getattr(est, "light_aware", None) or {}
    bp_ray = est.bp_ray
    ray_txt = _atxt(bp_ray, True)
    joint = getattr(est, "joint_cone_axis", None)
    if not est.isophotes and not la and joint is None and bp_ray is not None:
        # a rejected candidate: recommend() gives its BP ray (nothing else exists)
        head = f'{{"normal":{ray_txt},"normal_from":"bp_ray","depth_mm":null,"normal_sigma_deg":null,' \
               '"light_normals":null,"light_depths_mm":null,"light_aware":{}'
        prim, isos, la_txt, joint_txt = _NO_PRIMARY, "", _NO_LIGHT_AWARE_NORMALS, "null"
    else:
        isos, prim = [], None
        for iso in est.isophotes:
            text, parts = _isophote_json(iso, include_points)
            isos.append(text)
            if prim is None:
                prim = parts
        isos = ",".join(isos)
        prim = _NO_PRIMARY if prim is None else prim
        joint_txt = _atxt(joint, True)
        rec = est.recommended
        n = rec.normal
        # recommend() passes its source's array on (np.asarray): the same array, the same text
        if n is bp_ray:
            normal = ray_txt
        elif n is joint:
            normal = joint_txt
        elif est.isophotes and n is est.isophotes[0].cone_axis:
            normal = prim[7]
        else:
            normal = _atxt(n, True)
        la_dict = _light_aware_dict(la)
        head = (f'{{"normal":{normal},"normal_from":{_jstr(rec.normal_from)},"depth_mm":{_ftxt(rec.depth_mm)},'
                f'"normal_sigma_deg":{_ftxt(rec.normal_sigma_deg)},'
                f'"light_normals":{_json_or_null(_rows(getattr(rec, "light_normals", None)))},'
                f'"light_depths_mm":{_json_or_null(_nums(getattr(rec, "light_depths_mm", None)))},'
                f'"light_aware":{_json(la_dict) if la else "{}"}')
        la_txt = (",".join(f'"{name}":{_atxt(la[name].normal, True) if name in la else "null"}'
                           for name in LIGHT_AWARE_NORMALS) if la else _NO_LIGHT_AWARE_NORMALS)
    return (f'{head},"bp_px":{_atxt(est.bp_px, True)},"bp_intensity":{_ftxt(est.bp_intensity)},'
            f'"saturated":{"true" if est.saturated else "false"},'
            f'"roi":{_roi_txt(est.roi)},"status":{_jstr(est.status)},'
            f'"detail":{_jstr(est.detail)},"confidence":{_ftxt(getattr(est, "confidence", None))},'
            f'"normals":{{"paper":{prim[4]},"paper_selected":{prim[5]},"paper_selected_index":{prim[6]},'
            f'"cone_axis":{prim[7]},"joint_cone_axis":{joint_txt},"bp_ray":{ray_txt},{la_txt}}},'
            f'"ellipse":{prim[0]},"conic":{prim[1]},"fit_residual_px":{prim[2]},"eigenvalue_gap":{prim[3]},'
            f'"isophotes":[{isos}]}}')


def estimates_json(estimates, include_points: bool = False) -> str:
    """A list of estimates as the compact JSON array of their :func:`estimate_json` texts.

    Parameters
    ----------
    estimates : iterable of SpecularityEstimate
        One frame's estimates.
    include_points : bool
        Also write each isophote's contour points.

    Returns
    -------
    str
        ``json.dumps([estimate_to_dict(e, include_points) for e in estimates], allow_nan=False,
        separators=(",", ":"))``, character for character.

    Raises
    ------
    ValueError
        If a value is not finite.
    """
    ests = list(estimates)
    texts = _rejected_texts(ests)
    _fitted_texts(ests, texts, include_points)
    return "[" + ",".join([estimate_json(e, include_points) if t is None else t
                           for e, t in zip(ests, texts)]) + "]"


def _is_rejected(est) -> bool:
    """Whether :func:`estimate_json` writes ``est`` by its short path (a rejected candidate: no
    isophotes, no light-aware results, no joint axis, a BP ray)."""
    return (not est.isophotes and not getattr(est, "light_aware", None)
            and getattr(est, "joint_cone_axis", None) is None and est.bp_ray is not None)


#: The constant parts of a rejected candidate's text (:func:`estimate_json`'s short path).
_REJ_HEAD = '"normal_from":"bp_ray","depth_mm":null,"normal_sigma_deg":null,"light_normals":null,' \
            '"light_depths_mm":null,"light_aware":{}'
_REJ_NORMALS = '"normals":{"paper":null,"paper_selected":null,"paper_selected_index":null,"cone_axis":null,' \
               '"joint_cone_axis":null,"bp_ray":'
_REJ_TAIL = ('},"ellipse":null,"conic":null,"fit_residual_px":null,"eigenvalue_gap":null,"isophotes":[]}')


def _rows_txt(a: np.ndarray) -> list[str] | None:
    """The texts of the rows of a float64 array (n, k), as :func:`_atxt` writes each row, from
    one orjson call; None where that text is not json.dumps' (see :func:`_atxt`)."""
    t = _as_repr(_orjson.dumps(a, option=_ORJSON_NUMPY).decode())
    if t is None:
        return None
    return t[2:-2].split("],[")


def _rejected_texts(ests: list) -> list:
    """Each estimate's :func:`estimate_json` text where it is a rejected candidate's (most of a
    real frame's thousands), written for all of them at once: their BP rays, BPs and
    intensities each in one orjson call, the text of each then one format. None for the
    others, and for all where orjson's text is not json.dumps' (they take
    :func:`estimate_json`). The same text, character for character (``tests/test_io_fast.py``)."""
    out: list = [None] * len(ests)
    rej = [k for k, e in enumerate(ests) if _is_rejected(e)]
    if len(rej) < 2:
        return out
    try:
        rays = np.array([ests[k].bp_ray for k in rej], dtype=np.float64)
        bps = np.array([ests[k].bp_px for k in rej], dtype=np.float64)
        heights = np.array([ests[k].bp_intensity for k in rej], dtype=np.float64)
    except (TypeError, ValueError):  # ragged or odd values: one at a time
        return out
    if rays.shape != (len(rej), 3) or bps.shape != (len(rej), 2):
        return out
    ray_t, bp_t = _rows_txt(rays), _rows_txt(bps)
    h_t = _as_repr(_orjson.dumps(heights, option=_ORJSON_NUMPY).decode())
    if ray_t is None or bp_t is None or h_t is None:
        return out
    for k, ray, bp, h in zip(rej, ray_t, bp_t, h_t[1:-1].split(",")):
        e = ests[k]
        out[k] = (f'{{"normal":[{ray}],{_REJ_HEAD},"bp_px":[{bp}],"bp_intensity":{h},'
                  f'"saturated":{"true" if e.saturated else "false"},"roi":{_roi_txt(e.roi)},'
                  f'"status":{_jstr(e.status)},"detail":{_jstr(e.detail)},'
                  f'"confidence":{_ftxt(getattr(e, "confidence", None))},{_REJ_NORMALS}[{ray}],'
                  f'{_NO_LIGHT_AWARE_NORMALS}{_REJ_TAIL}')
    return out


def _array_texts(values: list, flat: bool) -> list:
    """:func:`_atxt` of each value, all written together: one float64 stack (``np.array`` of them,
    as :func:`_atxt` converts each), one orjson call, its text split at the items' brackets.
    ``null`` for None; None for every other value where they do not stack (shapes that differ,
    items that are not arrays of one or two dimensions, an empty one) or a value is not finite:
    :func:`_atxt` writes each then (and raises its error)."""
    out: list = ["null"] * len(values)
    ks = [k for k, x in enumerate(values) if x is not None]
    for k in ks:
        out[k] = None
    if len(ks) < 2:
        return out
    try:
        stack = np.array([values[k] for k in ks], dtype=np.float64)
    except (TypeError, ValueError):  # ragged, or not numbers
        return out
    if not stack.size or stack.ndim not in (2, 3) or (flat and stack.ndim == 3):
        return out
    t = _as_repr(_orjson.dumps(stack, option=_ORJSON_NUMPY).decode())
    if t is None:
        return out
    if stack.ndim == 2:  # "[[a,b],[c,d]]": each item between "],["
        for k, part in zip(ks, t[2:-2].split("],[")):
            out[k] = f"[{part}]"
    else:  # "[[[a,b],[c,d]],[[e,f],[g,h]]]": each item between "]],[["
        for k, part in zip(ks, t[3:-3].split("]],[[")):
            out[k] = f"[[{part}]]"
    return out


def _float_texts(values: list) -> list:
    """:func:`_ftxt` of each value, written together (one orjson call, or one repr of the list
    where orjson's text is not json.dumps'); None for all but the None values (``null``) where
    a value is not a finite number (:func:`_ftxt` raises its error)."""
    out: list = [None] * len(values)
    ks, fs = [], []
    try:
        for k, x in enumerate(values):
            if x is None:
                out[k] = "null"
            else:
                fs.append(float(x))
                ks.append(k)
    except (TypeError, ValueError):
        return out
    if not fs:
        return out
    t = _as_repr(_orjson.dumps(fs).decode())
    if t is None:
        return [None if x is not None else "null" for x in values]
    for k, part in zip(ks, t[1:-1].split(",")):
        out[k] = part
    return out


def _filled(texts: list, values: list, fn) -> list:
    """``texts`` with each None replaced by ``fn`` of its value (which raises as it would alone)."""
    return [fn(v) if t is None else t for t, v in zip(texts, values)]


def _fitted_texts(ests: list, out: list, include_points: bool) -> None:
    """Write into ``out`` each :func:`estimate_json` text left None there (the fitted candidates,
    with isophotes: a real frame's hundreds), the numbers of all of them written at once
    (:func:`_array_texts`, :func:`_float_texts`): their isophotes' ellipses, conics, normals and
    fit numbers, their BPs, BP rays and joint axes. The candidates with light-aware results, and
    all where any value would raise, are left None (:func:`estimate_json` then writes them, or
    raises its error). The same text, character for character (``tests/test_io_fast.py``)."""
    sel = [k for k, t in enumerate(out) if t is None and not getattr(ests[k], "light_aware", None)
           and not _is_rejected(ests[k])]
    if len(sel) < 2:
        return
    es = [ests[k] for k in sel]
    try:
        isos = [iso for e in es for iso in e.isophotes]
        ells = [iso.ellipse for iso in isos]
        cen = _filled(_array_texts([None if el is None else el.center for el in ells], True),
                      [None if el is None else el.center for el in ells], lambda v: _atxt(v, True))
        semi = _filled(_array_texts([None if el is None else el.semi_axes for el in ells], True),
                       [None if el is None else el.semi_axes for el in ells], lambda v: _atxt(v, True))
        angles = [None if el is None else float(el.angle_rad) * _DEG for el in ells]
        ang = _filled(_float_texts(angles), angles, _ftxt)
        cols = []
        for name, flat in (("conic", False), ("normals_paper", False), ("paper_selected", True),
                           ("cone_axis", True)):
            vals = [getattr(iso, name) for iso in isos]
            cols.append(_filled(_array_texts(vals, flat), vals, lambda v, f=flat: _atxt(v, f)))
        conic, paper, psel, cone = cols
        nums = []
        for name in ("isovalue", "fit_residual_px", "eigenvalue_gap"):
            vals = [getattr(iso, name) for iso in isos]
            nums.append(_filled(_float_texts(vals), vals, _ftxt))
        isoval, resid, gap = nums
        iso_txt, iso_parts = [], []
        for j, iso in enumerate(isos):
            ell = "null" if ells[j] is None else \
                f'{{"center_px":{cen[j]},"semi_axes_px":{semi[j]},"angle_deg":{ang[j]}}}'
            parts = (ell, conic[j], resid[j], gap[j], paper[j], psel[j], _int_txt(iso.paper_selected_index),
                     cone[j])
            iso_parts.append(parts)
            iso_txt.append(_isophote_text(iso, isoval[j], parts, include_points))
        rays = [e.bp_ray for e in es]
        ray_t = _filled(_array_texts(rays, True), rays, lambda v: _atxt(v, True))
        joints = [getattr(e, "joint_cone_axis", None) for e in es]
        joint_t = _filled(_array_texts(joints, True), joints, lambda v: _atxt(v, True))
        bps = [e.bp_px for e in es]
        bp_t = _filled(_array_texts(bps, True), bps, lambda v: _atxt(v, True))
        hs = [e.bp_intensity for e in es]
        h_t = _filled(_float_texts(hs), hs, _ftxt)
        confs = [getattr(e, "confidence", None) for e in es]
        conf_t = _filled(_float_texts(confs), confs, _ftxt)
        texts = []
        j = 0
        for i, est in enumerate(es):
            n_iso = len(est.isophotes)
            prim = iso_parts[j] if n_iso else _NO_PRIMARY
            isos_txt = ",".join(iso_txt[j:j + n_iso])
            j += n_iso
            bp_ray, joint = est.bp_ray, joints[i]
            rec = est.recommended
            n = rec.normal
            # as estimate_json: recommend() passes its source's array on
            if n is bp_ray:
                normal = ray_t[i]
            elif n is joint:
                normal = joint_t[i]
            elif n_iso and n is est.isophotes[0].cone_axis:
                normal = prim[7]
            else:
                normal = _atxt(n, True)
            texts.append(
                f'{{"normal":{normal},"normal_from":{_jstr(rec.normal_from)},"depth_mm":{_ftxt(rec.depth_mm)},'
                f'"normal_sigma_deg":{_ftxt(rec.normal_sigma_deg)},'
                f'"light_normals":{_json_or_null(_rows(getattr(rec, "light_normals", None)))},'
                f'"light_depths_mm":{_json_or_null(_nums(getattr(rec, "light_depths_mm", None)))},'
                f'"light_aware":{{}},"bp_px":{bp_t[i]},"bp_intensity":{h_t[i]},'
                f'"saturated":{"true" if est.saturated else "false"},'
                f'"roi":{_roi_txt(est.roi)},"status":{_jstr(est.status)},'
                f'"detail":{_jstr(est.detail)},"confidence":{conf_t[i]},'
                f'"normals":{{"paper":{prim[4]},"paper_selected":{prim[5]},"paper_selected_index":{prim[6]},'
                f'"cone_axis":{prim[7]},"joint_cone_axis":{joint_t[i]},"bp_ray":{ray_t[i]},'
                f'{_NO_LIGHT_AWARE_NORMALS}}},'
                f'"ellipse":{prim[0]},"conic":{prim[1]},"fit_residual_px":{prim[2]},"eigenvalue_gap":{prim[3]},'
                f'"isophotes":[{isos_txt}]}}')
    except (TypeError, ValueError, AttributeError):
        return  # a value one of them would raise on: estimate_json writes each, and raises
    for k, t in zip(sel, texts):
        out[k] = t


def estimates_document(estimates, *, K, image=None, image_shape=None, dist_coeffs=None,
                       isovalues=(), normalise="bp", include_points=False, camera=None,
                       lights=None, detection=None) -> dict:
    """The whole schema-2 document as a dict (see the module docstring).

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
        The camera model used, recorded as ``camera`` (its camera-file object).
    lights : LightRig, optional
        The light rig the light-aware estimators used (written as the camera file's list).
    detection : dict, optional
        What detection examined: ``{"components", "examined", "not_examined",
        "max_candidates"}`` (:meth:`~simtest.reconstruct.pipeline.Estimates.detection_record`);
        default the record ``estimates`` carries, if it is an ``Estimates``, else null.

    Returns
    -------
    dict
        ``schema``, ``simtest_version``, ``image``, ``image_shape``, ``K``, ``dist_coeffs``,
        ``isovalues``, ``normalise``, ``conventions``, ``detection`` and ``specularities`` (one
        :func:`estimate_to_dict` each).
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


def write_estimates(path, estimates, *, K, image=None, image_shape=None, dist_coeffs=None,
                    isovalues=(), normalise="bp", include_points=False, camera=None,
                    lights=None) -> Path:
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
        Recorded as given.
    include_points : bool
        Also write each isophote's contour points (larger file).

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ValueError
        If a value is not finite (JSON is written with ``allow_nan=False``); nothing is written.
    OSError
        If the folder is not writable.
    """
    doc = estimates_document(estimates, K=K, image=image, image_shape=image_shape,
                             dist_coeffs=dist_coeffs, isovalues=isovalues, normalise=normalise,
                             include_points=include_points, camera=camera, lights=lights)
    return atomic_write_json(path, doc, allow_nan=False)


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
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
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


# ------------------------------------------------------------------------------------------------
# an output folder replaced as a set (simtest._outdir)


#: What ``simtest reconstruct`` writes in its ``--out`` folder (and nothing else may be there).
RECONSTRUCT_FILES = ("estimates.json", "overlay.png", "view.png", "estimates.jsonl")
