"""``estimates.parquet``: a folder's or a video's estimates, one row per candidate.

:func:`table_schema` is the file's contract. :func:`estimates_batch` makes a frame's rows column
by column from its estimates, :func:`frame_batch` from a frame's record of dicts;
:func:`read_table` reads the file as a pyarrow Table and :func:`read_frames` reads it, or
``estimates.jsonl``, back into the per-frame records of :mod:`simtest.reconstruct.frames`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import orjson

from simtest._lazy import require
from simtest._version import __version__
from simtest.reconstruct.io import (LIGHT_AWARE_NORMALS, SCHEMA_VERSION, _light_aware_dict, _not_finite_at, _nums,
                                    _point_mm, _rows, dumps)

def arrow():
    """``(pyarrow, pyarrow.parquet)``, imported when a table is first made or read."""
    return require("pyarrow", purpose="estimates.parquet"), require("pyarrow.parquet", purpose="estimates.parquet")


#: The version of the table's columns (:func:`table_schema`); the file's ``simtest`` metadata.
TABLE_SCHEMA_VERSION = 1
#: The estimators' normals, ``normals`` of a specularity: each a column ``normal_<name>``.
_NORMAL_NAMES = ("paper", "paper_selected", "cone_axis", "joint_cone_axis", "bp_ray", *LIGHT_AWARE_NORMALS)
#: Rows of a Parquet row group (a video's frames gathered until then: a read skips whole groups).
ROW_GROUP_ROWS = 65536


def table_schema():
    """The Arrow schema of ``estimates.parquet``: one row per candidate, in frame order.

    Returns
    -------
    pyarrow.Schema
        ``frame`` (int32, from 0), ``source`` (the frame's file name or ``video:<index>``),
        ``candidate`` (int32, its index in the frame's ``specularities``), then the fields of an
        :func:`estimate_to_dict` dict with the same names, types and nulls, except ``normals``:
        each of its normals is a column ``normal_<name>`` (``normal_paper`` 2 x 3,
        ``normal_paper_selected``, ``normal_cone_axis``, ``normal_joint_cone_axis``,
        ``normal_bp_ray``, ``normal_isocurve_fit``, ``normal_photometric_fit``,
        ``normal_quadric_fit``, ``normal_cubic_patch_fit``: fixed-size lists of 3 float64) beside
        ``paper_selected_index``; an isophote's ``normals`` likewise. ``ellipse`` is a struct,
        ``light_aware`` a struct with one nullable struct per light-aware estimator (null: not
        run), ``isophotes`` a list of structs (``points_px`` null unless written with the points).
    """
    pa = arrow()[0]
    f64, text = pa.float64(), pa.string()
    v2, v3 = pa.list_(f64, 2), pa.list_(f64, 3)
    ellipse = pa.struct([("center_px", v2), ("semi_axes_px", v2), ("angle_deg", f64)])
    fit = [("ellipse", ellipse), ("conic", pa.list_(v3, 3)), ("fit_residual_px", f64), ("eigenvalue_gap", f64)]
    paper = [("normal_paper", pa.list_(v3, 2)), ("normal_paper_selected", v3),
             ("paper_selected_index", pa.int8()), ("normal_cone_axis", v3)]
    isophote = pa.struct([("isovalue", f64), ("status", text), ("detail", text), ("closed", pa.bool_()),
                          ("n_points", pa.int32()), *fit, *paper, ("points_px", pa.list_(v2))])
    light_aware = pa.struct([("status", text), ("detail", text), ("depth_mm", f64), ("normal_sigma_deg", f64),
                             ("depth_sigma_mm", f64), ("distance_mm", f64), ("roughness", f64), ("lobe", text),
                             ("projection", text), ("light_normals", pa.list_(v3)), ("light_depths_mm", pa.list_(f64)),
                             ("light_normal_sigmas_deg", pa.list_(f64)), ("depth_range_mm", pa.list_(f64))])
    return pa.schema([
        ("frame", pa.int32()), ("source", text), ("candidate", pa.int32()),
        ("normal", v3), ("normal_from", text), ("depth_mm", f64), ("point_mm", v3), ("normal_sigma_deg", f64),
        ("light_normals", pa.list_(v3)), ("light_depths_mm", pa.list_(f64)),
        ("bp_px", v2), ("bp_intensity", f64), ("saturated", pa.bool_()), ("roi", pa.list_(pa.int32(), 4)),
        ("status", text), ("detail", text), ("confidence", f64),
        *paper, ("normal_joint_cone_axis", v3), ("normal_bp_ray", v3),
        *((f"normal_{name}", v3) for name in LIGHT_AWARE_NORMALS),
        *fit,
        ("light_aware", pa.struct([(name, light_aware) for name in LIGHT_AWARE_NORMALS])),
        ("isophotes", pa.list_(isophote)),
    ])


def _flat_normals(d: dict) -> dict:
    """A specularity's or an isophote's dict with its ``normals`` as ``normal_<name>`` keys."""
    out = {k: v for k, v in d.items() if k != "normals"}
    for name, v in d["normals"].items():
        out[name if name == "paper_selected_index" else f"normal_{name}"] = v
    return out


def _nested_normals(row: dict, names) -> dict:
    """:func:`_flat_normals` undone: the ``normal_<name>`` keys of ``names`` back in ``normals``."""
    normals = {"paper": row.pop("normal_paper"), "paper_selected": row.pop("normal_paper_selected"),
               "paper_selected_index": row.pop("paper_selected_index")}
    for name in names[2:]:
        normals[name] = row.pop(f"normal_{name}")
    row["normals"] = normals
    return row


def frame_batch(record: dict):
    """A frame's record (:mod:`simtest.reconstruct.frames`) as rows of :func:`table_schema`.

    Parameters
    ----------
    record : dict
        ``frame``, ``source`` and ``specularities`` (:func:`estimate_to_dict` dicts).

    Returns
    -------
    pyarrow.RecordBatch
        One row per specularity, in order.

    Raises
    ------
    ValueError
        A value that is not finite (as in JSON: a missing value is null, never NaN), or a
        light-aware estimator the schema has no column for.
    """
    pa = arrow()[0]
    specs = record["specularities"]
    bad = _not_finite_at(specs, f"frame {record['source']}: specularities")
    if bad is not None:
        raise ValueError(f"value not finite: {bad}")
    rows = []
    for k, spec in enumerate(specs):
        row = _flat_normals(spec)
        unknown = set(spec["light_aware"]) - set(LIGHT_AWARE_NORMALS)
        if unknown:
            raise ValueError(f"frame {record['source']}: light-aware estimator(s) {sorted(unknown)} "
                             f"have no column in estimates.parquet")
        row["frame"], row["source"], row["candidate"] = record["frame"], record["source"], k
        row["isophotes"] = [_flat_normals(iso) for iso in spec["isophotes"]]
        rows.append(row)
    return pa.RecordBatch.from_pylist(rows, schema=table_schema())


def _fixed(values: list, shape: tuple, where: str):
    """A column of float64 arrays of ``shape`` from ``values`` (None: null); not finite refused."""
    pa = arrow()[0]
    n, size = len(values), math.prod(shape)
    null = np.array([v is None for v in values], dtype=bool)
    present = [v for v in values if v is not None]
    data = np.zeros((n, size))
    if present:
        try:
            stack = np.array(present, dtype=np.float64).reshape(len(present), size)
        except ValueError:
            raise ValueError(f"{where}: a value is not of shape {shape}") from None
        finite = np.isfinite(stack).all(axis=1)
        if not finite.all():
            row = int(np.flatnonzero(~null)[np.argmin(finite)])
            raise ValueError(f"value not finite: {where} of row {row}")
        data[~null] = stack
    arr = pa.array(data.reshape(-1))
    for k in reversed(shape[1:]):
        arr = pa.FixedSizeListArray.from_arrays(arr, k)
    return pa.FixedSizeListArray.from_arrays(arr, shape[0], mask=pa.array(null) if len(present) < n else None)


def _floats(values: list, where: str):
    """A float64 column (None: null), as :func:`_num` writes each; not finite refused."""
    pa = arrow()[0]
    null = np.array([v is None for v in values], dtype=bool)
    data = np.array([np.nan if v is None else float(v) for v in values], dtype=np.float64)
    bad = ~np.isfinite(data) & ~null
    if bad.any():
        raise ValueError(f"value not finite: {where} of row {int(np.flatnonzero(bad)[0])}")
    return pa.array(data, type=pa.float64(), mask=null)


def _ellipses(ells: list, where: str):
    pa = arrow()[0]
    center = _fixed([None if e is None else e.center for e in ells], (2,), f"{where}.center_px")
    semi = _fixed([None if e is None else e.semi_axes for e in ells], (2,), f"{where}.semi_axes_px")
    angle = _floats([None if e is None else float(np.degrees(e.angle_rad)) for e in ells], f"{where}.angle_deg")
    mask = pa.array([e is None for e in ells], type=pa.bool_())
    return pa.StructArray.from_arrays([center, semi, angle], names=["center_px", "semi_axes_px", "angle_deg"],
                                      mask=mask)


def _fit_columns(objs: list, indices: list, where: str) -> list:
    """The columns a specularity and an isophote share, from the estimates or isophotes ``objs``."""
    pa = arrow()[0]
    return [_ellipses([o.ellipse for o in objs], f"{where}.ellipse"),
            _fixed([o.conic for o in objs], (3, 3), f"{where}.conic"),
            _floats([o.fit_residual_px for o in objs], f"{where}.fit_residual_px"),
            _floats([o.eigenvalue_gap for o in objs], f"{where}.eigenvalue_gap"),
            _fixed([o.normals_paper for o in objs], (2, 3), f"{where}.normal_paper"),
            _fixed([o.paper_selected for o in objs], (3,), f"{where}.normal_paper_selected"),
            pa.array(indices, type=pa.int8()),
            _fixed([o.cone_axis for o in objs], (3,), f"{where}.normal_cone_axis")]


#: The columns of :func:`_fit_columns`, a specularity's and an isophote's alike.
_FIT_NAMES = ("ellipse", "conic", "fit_residual_px", "eigenvalue_gap", "normal_paper",
              "normal_paper_selected", "paper_selected_index", "normal_cone_axis")


def _isophotes(ests: list, include_points: bool, schema, where: str):
    """The ``isophotes`` column (a list of isophote structs per estimate) and the fit columns of
    each estimate's primary isophote (null where it has none), by name."""
    pa = arrow()[0]
    isos = [iso for e in ests for iso in e.isophotes]
    counts = np.array([len(e.isophotes) for e in ests], dtype=np.int32)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    pts = [iso.points_uv if include_points else None for iso in isos]
    lengths = [0 if p is None else len(p) for p in pts]
    points = pa.ListArray.from_arrays(
        pa.array(np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32)),
        _fixed([row for p in pts if p is not None for row in np.asarray(p, dtype=np.float64)], (2,),
               f"{where}.points_px"),
        mask=pa.array([p is None for p in pts], type=pa.bool_()))
    fit = _fit_columns(isos, [i.paper_selected_index for i in isos], where)
    fields = [pa.array([float(i.isovalue) for i in isos], type=pa.float64()),
              pa.array([i.status for i in isos], type=pa.string()),
              pa.array([i.detail for i in isos], type=pa.string()),
              pa.array([bool(i.closed) for i in isos], type=pa.bool_()),
              pa.array([0 if i.points_uv is None else len(i.points_uv) for i in isos], type=pa.int32()),
              *fit, points]
    struct = pa.StructArray.from_arrays(fields, fields=list(schema.field("isophotes").type.value_type))
    # a specularity's fit is its primary isophote's (the first): taken from the isophotes' columns
    primary = pa.array(offsets[:-1], type=pa.int32(), mask=counts == 0)
    return pa.ListArray.from_arrays(pa.array(offsets), struct), {
        name: col.take(primary) for name, col in zip(_FIT_NAMES, fit)}


def _recommended(ests: list) -> list:
    """Each estimate's recommended normal, None for a rejected detection (whose recommendation is its
    BP ray).
    """
    return [None if not e.isophotes and not getattr(e, "light_aware", None) and e.joint_cone_axis is None
            and e.bp_ray is not None else e.recommended for e in ests]


def estimates_batch(frame: int, source: str, ests, include_points: bool = False):
    """A frame's estimates as rows of :func:`table_schema`, column by column.

    Parameters
    ----------
    frame : int
        The frame's index.
    source : str
        The frame's file name or ``video:<index>``.
    ests : sequence of SpecularityEstimate
        The frame's estimates (after the light-aware step, if any).
    include_points : bool
        Also the isophotes' contour points.

    Returns
    -------
    pyarrow.RecordBatch
        The rows :func:`frame_batch` makes of their :func:`~simtest.reconstruct.io.estimate_to_dict` dicts.

    Raises
    ------
    ValueError
        Naming the column and row of a value that is not finite, or a light-aware estimator the
        schema has no column for.
    """
    pa = arrow()[0]
    ests = list(ests)
    n, schema = len(ests), table_schema()
    where = f"frame {source}"
    recs = _recommended(ests)
    las = [getattr(e, "light_aware", None) or {} for e in ests]
    for la in las:
        if la and set(la) - set(LIGHT_AWARE_NORMALS):
            raise ValueError(f"{where}: light-aware estimator(s) {sorted(set(la) - set(LIGHT_AWARE_NORMALS))} "
                             f"have no column in estimates.parquet")
    la_dicts = [_light_aware_dict(la) if la else {} for la in las]
    bad = _not_finite_at(la_dicts, f"{where}: light_aware")
    if bad is not None:
        raise ValueError(f"value not finite: {bad}")
    bp_rays = [e.bp_ray for e in ests]
    isophotes, column = _isophotes(ests, include_points, schema, f"{where}: isophotes")
    column.update({
        "frame": pa.array(np.full(n, frame, dtype=np.int32)),
        "source": pa.array([source] * n, type=pa.string()),
        "candidate": pa.array(np.arange(n, dtype=np.int32)),
        "normal": _fixed([ray if r is None else r.normal for r, ray in zip(recs, bp_rays)], (3,),
                         f"{where}: normal"),
        "normal_from": pa.array(["bp_ray" if r is None else r.normal_from for r in recs], type=pa.string()),
        "depth_mm": _floats([None if r is None else r.depth_mm for r in recs], f"{where}: depth_mm"),
        "point_mm": _fixed([None if r is None else _point_mm(r.depth_mm, ray) for r, ray in zip(recs, bp_rays)], (3,),
                           f"{where}: point_mm"),
        "normal_sigma_deg": _floats([None if r is None else r.normal_sigma_deg for r in recs],
                                    f"{where}: normal_sigma_deg"),
        "light_normals": pa.array([None if r is None else _rows(getattr(r, "light_normals", None)) for r in recs],
                                  type=schema.field("light_normals").type),
        "light_depths_mm": pa.array([None if r is None else _nums(getattr(r, "light_depths_mm", None))
                                     for r in recs], type=schema.field("light_depths_mm").type),
        "bp_px": _fixed([e.bp_px for e in ests], (2,), f"{where}: bp_px"),
        "bp_intensity": _floats([e.bp_intensity for e in ests], f"{where}: bp_intensity"),
        "saturated": pa.array([bool(e.saturated) for e in ests], type=pa.bool_()),
        "roi": pa.FixedSizeListArray.from_arrays(
            pa.array(np.array([[int(v) for v in e.roi] for e in ests], dtype=np.int32).reshape(-1)), 4),
        "status": pa.array([e.status for e in ests], type=pa.string()),
        "detail": pa.array([e.detail for e in ests], type=pa.string()),
        "confidence": _floats([getattr(e, "confidence", None) for e in ests], f"{where}: confidence"),
        "normal_joint_cone_axis": _fixed([e.joint_cone_axis for e in ests], (3,), f"{where}: joint_cone_axis"),
        "normal_bp_ray": _fixed(bp_rays, (3,), f"{where}: bp_ray"),
        "light_aware": pa.array(la_dicts, type=schema.field("light_aware").type),
        "isophotes": isophotes,
    })
    for name in LIGHT_AWARE_NORMALS:
        column[f"normal_{name}"] = _fixed([la[name].normal if name in la else None for la in las], (3,),
                                          f"{where}: {name}")
    return pa.RecordBatch.from_arrays([column[f.name] for f in schema], schema=schema)


def table_metadata(heads: list) -> dict:
    """The Parquet file's key-value metadata ``{"simtest": JSON text}``: ``table_schema``, ``schema``,
    ``simtest_version`` and ``frames`` (each frame's record but its specularities).
    """
    return {"simtest": dumps({"table_schema": TABLE_SCHEMA_VERSION, "schema": SCHEMA_VERSION,
                              "simtest_version": __version__, "frames": heads}).decode()}


def read_table(path):
    """Read ``estimates.parquet``.

    Parameters
    ----------
    path : str or Path
        The file (``simtest reconstruct`` on a folder or a video).

    Returns
    -------
    pyarrow.Table
        Rows of :func:`table_schema`; its ``schema.metadata[b"simtest"]`` is the file's metadata
        (:func:`table_metadata`; :func:`read_frames` reads it).

    Raises
    ------
    ValueError
        Naming the file: not readable as Parquet, or not written by simtest.
    """
    pa, pq = arrow()
    path = Path(path)
    try:
        with pq.ParquetFile(path) as f:
            meta = f.metadata.metadata or {}
            table = f.read()
    except (OSError, pa.ArrowException) as exc:
        raise ValueError(f"{path}: cannot read Parquet ({exc})") from None
    if b"simtest" not in meta:
        raise ValueError(f"{path}: no 'simtest' metadata: not an estimates table written by simtest")
    info = orjson.loads(meta[b"simtest"])
    if info.get("table_schema") != TABLE_SCHEMA_VERSION:
        raise ValueError(f"{path}: table_schema is {info.get('table_schema')!r}, expected {TABLE_SCHEMA_VERSION}")
    return table.replace_schema_metadata({"simtest": meta[b"simtest"]})


def read_frames(path) -> list[dict]:
    """The per-frame records of ``estimates.parquet`` or ``estimates.jsonl``, alike.

    Parameters
    ----------
    path : str or Path
        A ``.parquet`` file (:func:`read_table`) or a JSON Lines file (anything else).

    Returns
    -------
    list of dict
        One record per frame, in order: ``frame``, ``source``, ``image_shape``, ``counts``,
        ``normals_from``, ``detection`` and ``specularities`` (dicts of :func:`estimate_to_dict`, as
        ``estimates.json`` holds them), the same from either file.

    Raises
    ------
    ValueError
        Naming the file and the line: unreadable, or not an object.
    """
    path = Path(path)
    if path.suffix.lower() == ".parquet":
        table = read_table(path)
        heads = orjson.loads(table.schema.metadata[b"simtest"])["frames"]
        records = {h["frame"]: {**h, "specularities": []} for h in heads}
        for row in table.to_pylist():
            frame = row.pop("frame")
            del row["source"], row["candidate"]
            row["light_aware"] = {k: v for k, v in row["light_aware"].items() if v is not None}
            isos = []
            for iso in row["isophotes"]:
                if iso["points_px"] is None:
                    del iso["points_px"]
                isos.append(_nested_normals(iso, _NORMAL_NAMES[:3]))
            row["isophotes"] = isos
            records[frame]["specularities"].append(_nested_normals(row, _NORMAL_NAMES))
        return list(records.values())
    out = []
    try:
        with open(path, "rb") as fh:
            for n, line in enumerate(fh, 1):
                rec = orjson.loads(line)
                if not isinstance(rec, dict):
                    raise ValueError(f"{path}: line {n} is not a JSON object")
                out.append(rec)
    except (OSError, orjson.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read JSON Lines ({exc})") from None
    return out


