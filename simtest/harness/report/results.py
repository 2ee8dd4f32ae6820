"""The ``results.json`` document of a suite run and the CSV beside it.

``results.json`` (schema :data:`SCHEMA`, version :data:`SCHEMA_VERSION`)::
    {"schema": "simtest.validation", "schema_version": 2, "run_id": ..., "created_utc": ...,
     "suite": {"name", "description", "source", "sha256", "seed", "realisations", "estimators"},
     "seeding": "...", "estimators": {name: text},
     "provenance": {"git_commit", "git_dirty", "git_dirty_files", "packages", "mitsuba_variants",
        "python", "machine", "workers", "started_utc", "wall_time_s", "realisations_per_s"},
     "open_parameters": {name: {"value", "why"}},
     "families": {family: {"protocol", "colocated", "cases": [case ids], "images", "end_to_end",
                           "false_positives", "false_positives_per_image",
                           "estimators": {name: statistics pooled over its unique cases}}},
     "sweeps": [{"name", "protocol", "parameter", "label", "display_scale", "description",
                 "cases": [case ids], "paper": {...} | null, "comparison": [...]}],
     "claims": [{"id", "source", "claim", "holds", "measured", "scope"}],
     "cases": [{"id" (<sweep>@<x>), "key" (seeds the case), "sweep", "protocol", "scene",
                "family", "colocated", "params", "x", "realisations", "samples",
                "metrics": {"end_to_end": {...} | null (:mod:`simtest.harness.end_to_end`),
                            "estimators": {name: {n, n_ok, failure_rate, failures, mean, std,
                                                   median, p5, p95, min, max}},
                            "diagnostics": {name: mean or null}},
                "exceptions": [...]}]}

Angles in degrees. A *family* groups the cases by what is seen: the paper's synthetic protocol,
or a rendered geometry (plane, sphere, cylinder, saddle, liver, colon, or the scene name for
anything else), with ``", light offset"`` appended when the light is off the camera centre
(``" under a light rig, light offset"`` for a rig of lights beside the lens). The
numbers under ``cases`` and ``families`` depend only on the suite and the seed, never on the
number of workers; provenance (times, machine) differs between runs.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io

import numpy as np

from simtest.harness.claims import evaluate_claims, evaluate_paper_claim
from simtest.harness.metrics import STAT_KEYS, case_metrics, summarise, summarise_records
from simtest.harness.report.provenance import open_parameters, provenance, relative_to_repo
from simtest.reconstruct.registry import describe
from simtest.scene import load_scene

__all__ = ["SCHEMA", "SCHEMA_VERSION", "SEEDING", "build_results", "case_family", "results_csv"]

SCHEMA = "simtest.validation"
SCHEMA_VERSION = 2

SEEDING = ("realisation i of a case draws from numpy SeedSequence([root_seed, "
           "int.from_bytes(sha256(case_key)[:8], 'little'), i]); rendered cases take the render "
           "seed as the first 31-bit word of that sequence")


_MESH_KEYS = {"colon_station": "colon", "liver_azimuth_deg": "liver"}


def case_family(case) -> tuple[str, bool]:
    """The scene family of a case and whether its light is co-located with the camera.

    Parameters
    ----------
    case : simtest.harness.suite.Case
        A ``paper`` or ``rendered`` case.

    Returns
    -------
    family : str
        ``"paper protocol"`` for the paper's synthetic protocol; for rendered cases the geometry
        (``"colon"``, ``"liver"``, the scene's ``geometry.type``, or the scene name when it
        cannot be read), plus ``", light offset"`` when the light is off the camera centre, and
        ``" under a light rig, light offset"`` for a rig of lights beside the lens (``light.rig``
        other than "single"), kept apart from one offset light.
    colocated : bool
        False for the paper protocol (its slanted camera does not carry the light), for a
        rendered light offset > 0 and for a light rig (``light.rig`` other than "single").
    """
    if case.protocol == "paper":
        return "paper protocol", False
    p = case.params
    family = next((name for key, name in _MESH_KEYS.items() if p.get(key) is not None), None)
    eps, rig = p.get("light.epsilon_mm"), p.get("light.rig")
    if family is None or eps is None or rig is None:
        try:
            spec = load_scene(case.scene)
            family = family or str(p.get("geometry.type") or spec.geometry.type)
            eps = getattr(spec.light, "epsilon_mm", 0.0) if eps is None else eps
            rig = getattr(spec.light, "rig", "single") if rig is None else rig
        except Exception:  # noqa: BLE001 - a family name is a label, never a reason to fail
            family = family or str(case.scene_name)
    # a light rig (light guides beside the lens) is never at the camera centre; its family is
    # kept apart from one offset light's, which it can beat (two lobes fix the depth)
    if rig not in (None, "single"):
        return f"{family} under a light rig, light offset", False
    colocated = not (eps or 0.0) > 0
    return (family if colocated else f"{family}, light offset"), colocated


def _families(run, cases: list[dict]) -> dict:
    fam: dict[str, dict] = {}
    seen: set[tuple] = set()
    for r, d in zip(run.results, cases):
        f = fam.setdefault(d["family"], {"protocol": d["protocol"], "colocated": d["colocated"],
                                         "cases": [], "_err": {}, "_cause": {}, "_fp": [], "images": 0, "_e2e": []})
        f["cases"].append(d["id"])
        key = (r.case.key, r.case.realisations)
        if key in seen:  # a setting shared by two sweeps is pooled once
            continue
        seen.add(key)
        for e in run.suite.estimators:
            f["_err"].setdefault(e, []).append(np.asarray(r.errors[e], dtype=np.float64))
            f["_cause"].setdefault(e, []).extend(r.causes[e])
        fp = np.asarray(r.extras.get("false_positives", []), dtype=np.float64)
        f["_fp"].append(fp[np.isfinite(fp)])
        f["_e2e"] += getattr(r, "e2e", [])
        f["images"] += int(r.case.realisations)
    out = {}
    for name, f in fam.items():
        fp = np.concatenate(f["_fp"]) if f["_fp"] else np.zeros(0)
        out[name] = {
            "protocol": f["protocol"], "colocated": f["colocated"], "cases": f["cases"],
            "images": f["images"], "end_to_end": summarise_records(f["_e2e"]),
            # None where the protocol does not detect (the paper protocol knows its BP)
            "false_positives": int(fp.sum()) if fp.size else None,
            "false_positives_per_image": float(fp.mean()) if fp.size else None,
            "estimators": {e: summarise(np.concatenate(v), f["_cause"][e]) for e, v in f["_err"].items()},
        }
    return out


def build_results(run, run_id: str) -> dict:
    """The ``results.json`` document of a suite run (schema in the module docstring).

    Parameters
    ----------
    run : simtest.harness.runner.SuiteRun
        The finished run.
    run_id : str
        Id written in the document (see :func:`simtest.harness.report.make_run_id`).

    Returns
    -------
    dict
        JSON-ready document (angles in degrees); the ``cases`` and ``families`` numbers depend
        only on the suite and its seed. ``claims`` holds the verdict of every claim of
        :data:`simtest.harness.claims.CLAIMS` that the suite's cases can decide.
    """
    suite = run.suite
    cases = []
    for r in run.results:
        d = r.case.to_dict()
        d["family"], d["colocated"] = case_family(r.case)
        d["metrics"] = case_metrics(r)
        d["samples"] = int(r.realisation.size)
        d["exceptions"] = list(r.exceptions)
        cases.append(d)
    sweeps = []
    for sw in suite.sweeps:
        sc = [c for c in cases if c["sweep"] == sw.name]
        entry = {"name": sw.name, "protocol": sw.protocol, "parameter": sw.parameter, "label": sw.label,
                 "display_scale": sw.display_scale, "description": sw.description,
                 "cases": [c["id"] for c in sc], "paper": sw.paper,
                 "comparison": evaluate_paper_claim(sw.paper, sc) if sw.paper else []}
        sweeps.append(entry)
    doc = {
        "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "run_id": run_id,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "suite": {"name": suite.name, "description": suite.description, "source": relative_to_repo(suite.source),
                  "sha256": suite.sha256, "seed": suite.seed, "realisations": suite.realisations,
                  "estimators": list(suite.estimators)},
        "seeding": SEEDING, "estimators": {k: describe(k) for k in suite.estimators}, "provenance": provenance(run),
        "open_parameters": open_parameters(suite), "families": _families(run, cases), "sweeps": sweeps,
        "cases": cases,
    }
    doc["claims"] = evaluate_claims(doc)
    return doc


def results_csv(results: dict) -> str:
    """Every case x estimator statistic of a ``results.json`` document as CSV text.

    Parameters
    ----------
    results : dict
        The document.

    Returns
    -------
    str
        Header ``case,sweep,family,x,estimator,n,n_ok,failure_rate,mean,std,median,p5,p95,min,
        max`` (x in display units, errors in degrees; empty where an estimator never succeeded),
        then one row per case and estimator in results order.
    """
    scale = {sw["name"]: sw["display_scale"] for sw in results["sweeps"]}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["case", "sweep", "family", "x", "estimator", "n", "n_ok", "failure_rate", *STAT_KEYS])
    for c in results["cases"]:
        for e, m in c["metrics"]["estimators"].items():
            w.writerow([c["id"], c["sweep"], c.get("family", ""),
                        repr(c["x"] * scale.get(c["sweep"], 1.0)), e, m["n"], m["n_ok"], repr(m["failure_rate"]),
                        *["" if m.get(k) is None else repr(m[k]) for k in STAT_KEYS]])
    return buf.getvalue()
