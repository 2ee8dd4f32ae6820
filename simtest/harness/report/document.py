"""``report.md`` from a ``results.json`` document, and a self-contained ``report.html`` from it.

The Markdown opens with the end-to-end figures per family, then the summary given the highlight
(family x estimator table, claim verdicts, alarming cells explained), provenance and per-sweep
details; every number is formatted from the document. The HTML is that Markdown rendered by
markdown-it-py with every figure inlined as a base64 PNG.
"""

from __future__ import annotations

import base64
import html
import json

from markdown_it import MarkdownIt

from simtest.decisions import data_side
from simtest.harness.claims import ALARM_DEG, BEST_LEVEL, MIN_N_INTERVAL, best_marks
from simtest.harness.explain import explanations
from simtest.harness.report.figures import takeaways
from simtest.harness.report.numbers import esc, fmt
from simtest.tolerances import TOL

__all__ = ["markdown_report", "html_report", "fmt", "cell", "summary_markdown", "end_to_end_markdown"]

#: Diagnostics listed per sweep (means over the scored highlights), in this order.
_DIAG_ORDER = ("false_positives", "saturated_px", "bp_error_px", "residual_px", "eigenvalue_gap",
               "predicted_gap", "pose_split_deg", "predicted_pose_deg", "rho", "bp_distance_mm",
               "k1_per_mm", "k2_per_mm", "iso_radius_mm")

_DIAG_TEXT = {
    "false_positives": "false positives per image (detections farther than match_px from every true BP)",
    "saturated_px": "pixels at the sensor's full scale per image (clipped)",
    "bp_error_px": "distance from the detected to the true BP, px",
    "residual_px": "ellipse fit residual, px",
    "eigenvalue_gap": "measured eigenvalue gap (l1 - l2) / (l1 - l3) of C' (0: right circular cone)",
    "predicted_gap": "gap predicted from the curvatures, 1 - rho^2",
    "pose_split_deg": "angle between N+ and N-, deg",
    "predicted_pose_deg": "circle-pose error predicted from the curvatures, asin(sqrt(1 - rho^2)), deg",
    "rho": "rho = |1 + k2 d| / |1 + k1 d| (1: isotropic)",
    "bp_distance_mm": "distance d from the camera to the true BP, mm",
    "k1_per_mm": "principal curvature k1 at the true BP, 1/mm (positive: convex toward the camera)",
    "k2_per_mm": "principal curvature k2 <= k1, 1/mm",
    "iso_radius_mm": "isophote radius on the surface estimated from the fitted ellipse, mm",
    "eps_over_d": "light offset over distance: the rig's farthest light from the camera centre "
                  "over the distance to the true BP",
    "recommended_bp_ray_share": "share of the highlights where the recommendation fell back to the BP ray",
    "recommended_within_2sigma": "share of the highlights with a stated sigma whose recommended "
                                 "normal's error is at most twice it",
    "recommended_depth_within_2sigma": "share of the highlights with a recommended depth and a "
                                       "stated depth sigma whose depth errs by at most twice it",
    "recommended_beyond_bp_ray": "share of the highlights with a stated sigma whose recommended "
                                 "normal errs by more than the BP ray's error plus that sigma",
    "cubic_patch_fit_ok_share": "share of the highlights where cubic_patch_fit's status is ok",
    "cubic_patch_fit_misfit_share": "share of the highlights where cubic_patch_fit's patch "
                                    "misfits the ROI (patch_misfit)",
    "specular_separation_mm": "distance between the specular points of two lights of the rig "
                              "(this highlight's and the nearest one of another light), mm",
    "curvature_change_rel": "change of the principal curvatures between those two specular "
                            "points, |dk| / |k| (a third-order patch holds while it is small)",
}
#: Texts of the per-estimator diagnostics ``<estimator><suffix>``.
_DIAG_SUFFIX_TEXT = {
    "_depth_err_pct": "{est}: depth error |depth / true - 1|, %",
    "_depth_err_pct_median": "{est}: median depth error |depth / true - 1|, %",
    "_within_2sigma_n": "{est}: highlights with a stated sigma (the share's count)",
    "_beyond_bp_ray_n": "{est}: highlights with a stated sigma and a BP ray (the share's count)",
    "_depth_rel_sigma": "{est}: relative 1-sigma of its depth at the noise floor (above "
                        f"{TOL.depth_rel_sigma_max:g}: not observable)",
}


def _diag_text(key: str) -> str:
    """What a diagnostics column holds: its text, a per-estimator text, or the key itself."""
    if key in _DIAG_TEXT:
        return _DIAG_TEXT[key]
    for suffix, text in _DIAG_SUFFIX_TEXT.items():
        if key.endswith(suffix):
            return text.format(est=key[: -len(suffix)])
    return key


def cell(m: dict | None, show_fail: bool = True) -> str:
    """One table cell: ``median [p5, p95] (n)`` in degrees, plus the failure rate when not 0.

    Parameters
    ----------
    m : dict or None
        Statistics of :func:`simtest.harness.metrics.summarise`.
    show_fail : bool
        Append ``, fail x %`` when some realisations failed.

    Returns
    -------
    str
        ``-`` when the estimator never succeeded (with the failure rate).
    """
    if not m:
        return "-"
    fail = m.get("failure_rate") or 0.0
    ftxt = f", fail {100 * fail:.3g} %" if show_fail and fail > 0 else ""
    if m.get("median") is None:
        return f"- (n {m.get('n', 0)}){ftxt}"
    return (f"{fmt(m['median'])} [{fmt(m.get('p5'))}, {fmt(m.get('p95'))}] (n {m.get('n_ok', m.get('n', 0))}){ftxt}")


_VERDICT = {True: "holds", False: "**does not hold**", None: "undecided"}
#: A summary cell as :func:`simtest.harness.claims.best_marks` marks it.
_MARKED = {"best": "**{}** (best)", "tie": "{} (tie)"}

#: How the summary marks the lowest median (:func:`simtest.harness.claims.best_marks`).
BEST_RULE = (f"A row's lowest median is in bold, marked (best), only where it is below every "
             f"other by more than the {100 * BEST_LEVEL:g} % confidence interval of the "
             "difference (t interval of two medians, each with standard error "
             "(p95 - p5) / (1.8 sqrt(n))); the estimators it cannot be told apart from are "
             f"marked (tie), and an estimator with fewer than {MIN_N_INTERVAL} successes ties "
             "with every one; no mark where all tie.")


def lobe_cell(e: dict) -> str:
    """``"<ok on a lobe per frame> (<median error> deg)"`` of end-to-end figures ``e`` ("-" before lobes were scored)."""
    if e.get("lobe_ok_per_frame") is None:
        return "-"
    med = e.get("median_lobe_ok_deg")
    return fmt(e["lobe_ok_per_frame"]) + ("" if med is None else f" ({fmt(med)} deg)")


def end_to_end_markdown(results: dict) -> list[str]:
    """The report's headline: per family, what ``simtest render`` + ``simtest reconstruct`` give a
    user (:mod:`simtest.harness.end_to_end`); no lines where no family has end-to-end records."""
    fams = {k: f["end_to_end"] for k, f in results.get("families", {}).items() if f.get("end_to_end")}
    if not fams:
        return []
    L = ["## End to end: what `simtest render` + `simtest reconstruct` give a user", "",
         "Each true highlight of every rendered frame, through `simtest reconstruct`'s own call with its "
         "defaults and the render's `camera.json` (model, light rig, response): detected (a detection "
         f"within {fmt(next(iter(fams.values()))['match_px'])} px), status ok, the share whose "
         "recommended normal (whatever its status: what the user gets) errs at most 1 and 5 deg, the "
         "median error over those ok, false ok per frame (ok detections far from every true highlight and "
         "on no specular lobe), ok per frame on a lobe's peak where a curved surface's normal nears the "
         "bisector without an exact BP (median error against the surface normal there), "
         "and what the recommended normals came from.", "",
         "| family | highlights | detected | ok | within 1 deg | within 5 deg | median ok (n) "
         "| false ok per frame | ok on a lobe per frame (median) | normal from |", "|---" * 10 + "|"]
    for name, e in fams.items():
        pct = {k: "-" if e[k] is None else f"{100 * e[k]:.3g} %"
               for k in ("detected", "ok", "within_1deg", "within_5deg")}
        src = ", ".join(f"{k} {v}" for k, v in e["normal_from"].items())
        L.append(f"| {esc(name)} | {e['n']} | {pct['detected']} | {pct['ok']} | {pct['within_1deg']} "
                 f"| {pct['within_5deg']} | {fmt(e['median_ok_deg'])} (n {e['n_ok']}) "
                 f"| {fmt(e['false_ok_per_frame'])} | {lobe_cell(e)} | {esc(src)} |")
    return L + [""]


def summary_markdown(results: dict) -> list[str]:
    """The summary section: family x estimator table, claim verdicts, alarming cells explained.

    Parameters
    ----------
    results : dict
        A ``results.json`` document (schema 2: ``families`` and ``claims``).

    Returns
    -------
    list of str
        Markdown lines.
    """
    ests = results["suite"]["estimators"]
    fams = results.get("families", {})
    L = ["## Summary given the highlight (not end to end)", ""]
    if fams:
        L += ["Given the highlight, not end to end: each estimator on the harness's own detection "
              "(the case's settings), the BP ray, light-aware fits and recommendation scored on every "
              "matched true highlight whatever its status. "
              "Median normal error in degrees [5th, 95th percentile] (n scored specularities), "
              "pooled over every case of the scene family; the failure rate when some "
              "realisations failed. " + BEST_RULE + " False positives: "
              "detections with no true highlight within match_px (per image; the paper protocol "
              "knows its BP and detects nothing).", "",
              "| family | images | false positives | " + " | ".join(ests) + " |",
              "|---" * (len(ests) + 3) + "|"]
        for name, f in fams.items():
            marks = best_marks({e: f["estimators"].get(e) for e in ests})
            cells = [_MARKED.get(marks.get(e), "{}").format(cell(f["estimators"].get(e))) for e in ests]
            fp = ("n/a" if f.get("false_positives") is None else
                  f"{f['false_positives']} ({fmt(f['false_positives_per_image'])} per image)")
            col = "" if f.get("colocated") else " (light not at the camera)"
            L.append(f"| {esc(name)}{col} | {f['images']} | {fp} | " + " | ".join(cells) + " |")
        L.append("")
    claims = results.get("claims", [])
    if claims:
        L += ["### Verdicts", "",
              "Each claim is checked on this run's results (the paper's figure-3 statements, and "
              "predictions of ours from the geometry of a co-located light).", "",
              "| claim | source | verdict | measured | scope |", "|---|---|---|---|---|"]
        L += [f"| {esc(c['claim'])} | {c['source']} | {_VERDICT[c['holds']]} | {esc(c['measured'])} | "
              f"{esc(c['scope'])} |" for c in claims] + [""]
    expl = explanations(results)
    if expl:
        L += [f"### Why some rows are alarming (family median above {ALARM_DEG:g} deg, or a "
              "case far above its family)", ""]
        L += [f"- {x['family']}, `{x['estimator']}` (median {fmt(x['median'])} deg): "
              + (x["text"] if x["text"] else "no rule of the report explains it; see the sweep details below")
              for x in expl] + [""]
    return L


def _figure(name: str, notes: dict[str, str]) -> list[str]:
    """A figure's Markdown lines: the image, then its takeaway sentence when it has one."""
    L = [f"![{name}](figures/{name})", ""]
    if notes.get(name):
        L += [f"Takeaway: {esc(notes[name])}", ""]
    return L


def _nightly_markdown(nightly: dict, figures: list[str], notes: dict[str, str]) -> list[str]:
    L = ["## Nightly gate", "",
         f"Verdict: **{nightly['verdict']}** against `{nightly.get('baseline', '')}` "
         f"({nightly.get('summary', '')}).", ""]
    if nightly.get("problems"):
        L += [f"- {esc(p)}" for p in nightly["problems"]] + [""]
    if "nightly_trend.png" in figures:
        L += _figure("nightly_trend.png", notes)
    return L


def markdown_report(results: dict, figures: list[str], nightly: dict | None = None,
                    history: list[dict] | None = None) -> str:
    """The ``report.md`` text of a results document.

    Parameters
    ----------
    results : dict
        A ``results.json`` document.
    figures : list of str
        File names of the figures written under ``figures/``.
    nightly : dict, optional
        The nightly gate's outcome: ``verdict``, ``baseline``, ``summary``, ``problems``.
    history : list of dict, optional
        Nightly history lines.

    Returns
    -------
    str
        Markdown (CommonMark with tables); each figure followed by one ``Takeaway:`` sentence.
    """
    notes = takeaways(results, history)
    s, p = results["suite"], results["provenance"]
    cases = {c["id"]: c for c in results["cases"]}
    # the console header's and the progress bar's count: distinct (key, realisations) settings
    # run once, whatever number of sweeps share them
    distinct = {(c["key"], c["realisations"]): c["realisations"] for c in results["cases"]}
    n_unique, n_real = len(distinct), sum(distinct.values())
    L = [f"# Validation report: {s['name']}", ""]
    if s["description"]:
        L += [s["description"], ""]
    L += end_to_end_markdown(results) + summary_markdown(results)
    if nightly:
        L += _nightly_markdown(nightly, figures, notes)
    dirty = (f", plus uncommitted changes to {', '.join(p.get('git_dirty_files') or [])}"
             if p.get("git_dirty") else " (clean)" if p.get("git_dirty") is False else "")
    L += ["## Run", "",
          f"- run id `{results['run_id']}` ({results['created_utc']}), suite file "
          f"`{s['source']}` (sha256 {s['sha256'][:12]}): {len(results['sweeps'])} sweeps, "
          f"{len(results['cases'])} cases = {n_unique} distinct settings (a setting shared by "
          f"several sweeps runs once), {n_real} realisations",
          f"- git commit `{p['git_commit']}`{dirty}; Mitsuba variant(s): "
          f"{', '.join(p['mitsuba_variants']) or 'none (no render)'}",
          f"- machine: {p['machine']['platform']}, {p['machine']['cpu_count']} CPUs"
          f"{'; BLAS ' + ', '.join(p['machine']['blas']) if p['machine'].get('blas') else ''}; "
          f"{p['workers']} worker(s), wall time {p['wall_time_s']:.1f} s",
          "- speed: " + "; ".join(f"{k}: {v['realisations']} realisations, {fmt(v['per_s'])} realisations/s"
                                  for k, v in p["realisations_per_s"].items()),
          f"- root seed {s['seed']}: {data_side(s['seed']).replace('_', '-')} data (a seed the decisions "
          f"of simtest/decisions.py were chosen on is tuning data); {results['seeding']}",
          "- errors: angle between the estimated and true normals, atan2(|a x b|, a . b), "
          "degrees; statistics over the realisations where the estimator succeeded, failures "
          "counted by cause; every statistic is in `results.json` and `results.csv`", ""]
    L += ["## Estimators", ""] + [f"- `{k}`: {v}" for k, v in results["estimators"].items()] + [""]
    comp = [sw for sw in results["sweeps"] if sw.get("paper")]
    if comp:
        L += ["## Claims per sweep", "",
              "| sweep | source | claim | ours | holds | note |", "|---|---|---|---|---|---|"]
        for sw in comp:
            ours = "; ".join(c["ours"] for c in sw["comparison"]) or "-"
            holds = ", ".join({True: "yes", False: "no", None: "n/a"}[c["holds"]] for c in sw["comparison"]) or "-"
            L.append(f"| {sw['name']} | {sw['paper'].get('source', 'paper')} | "
                     f"{esc(sw['paper'].get('claim', ''))} | {esc(ours)} | {holds} | "
                     f"{esc(sw['paper'].get('note', ''))} |")
        L.append("")
    if "curvature_rho.png" in figures:
        L += ["## Curvature: what rho predicts", "",
              "Each point is one rendered curved case (means over its highlights). rho = "
              "|1 + k2 d| / |1 + k1 d| with d the distance to the BP and k1 >= k2 the signed "
              "principal curvatures there (positive where the patch bulges toward the camera, "
              "negative inside a lumen). A co-located light makes the isophote cone elliptic "
              "with its axis on the normal; its eigenvalue gap is 1 - rho^2 and the circle-pose "
              "normals N+ and N- leave the axis by asin(sqrt(1 - rho^2)), whatever the isophote "
              "size. Points on the dashed line agree with the prediction.", ""]
        L += _figure("curvature_rho.png", notes)
    if results.get("open_parameters"):
        L += ["## Parameters the paper leaves open (our choices)", ""] + [
            f"- `{k}` = {json.dumps(v['value'])}: {v['why']}" for k, v in results["open_parameters"].items()] + [""]
    ests = s["estimators"]
    for sw in results["sweeps"]:
        L += [f"## Sweep `{sw['name']}` ({sw['protocol']}): {sw['label']}", ""]
        if sw.get("description"):
            L += [sw["description"], ""]
        L += ["Median error (deg) [p5, p95] (n successes); failures by cause.", "",
              f"| {esc(sw['label'])} | " + " | ".join(ests) + " | failures |", "|---" * (len(ests) + 2) + "|"]
        for key in sw["cases"]:
            c = cases[key]
            fails: dict[str, int] = {}
            for e in ests:
                for cause, n in c["metrics"]["estimators"][e]["failures"].items():
                    fails[cause] = max(fails.get(cause, 0), n)
            n = c["metrics"]["estimators"][ests[0]]["n"]
            ftxt = ", ".join(f"{k}: {v}" for k, v in sorted(fails.items())) or "0"
            L.append(f"| {c['x'] * sw['display_scale']:g} | "
                     + " | ".join(cell(c["metrics"]["estimators"][e], show_fail=False) for e in ests)
                     + f" | {ftxt} of {n} |")
        L.append("")
        diag = [cases[k]["metrics"].get("diagnostics", {}) for k in sw["cases"]]
        keys = [k for k in _DIAG_ORDER if any(d.get(k) is not None for d in diag)]
        keys += sorted({k for d in diag for k, v in d.items() if v is not None and k not in keys and k not in
                        ("r_k1", "r_k2", "anisotropy")})
        if keys:
            L += ["Diagnostics (means over the scored highlights): "
                  + "; ".join(f"`{k}`: {_diag_text(k)}" for k in keys) + ".", "",
                  f"| {esc(sw['label'])} | " + " | ".join(keys) + " |", "|---" * (len(keys) + 1) + "|"]
            for key, d in zip(sw["cases"], diag):
                L.append(f"| {cases[key]['x'] * sw['display_scale']:g} | "
                         + " | ".join(fmt(d.get(k)) for k in keys) + " |")
            L.append("")
        for f in (f"{sw['name']}_curves.png", f"{sw['name']}_bars.png"):
            if f in figures:  # by full name: sweep "isovalue" must not take "isovalue_unbounded_*"
                L += _figure(f, notes)
        exc = [(cases[k]["x"], e) for k in sw["cases"] for e in cases[k]["exceptions"]]
        if exc:
            L += ["Exceptions (first of each case):", ""] + [f"- x = {x:g}: `{e}`" for x, e in exc] + [""]
    return "\n".join(L) + "\n"


_CSS = """body{font-family:system-ui,sans-serif;max-width:1300px;margin:2em auto;padding:0 1em;
color:#222}table{border-collapse:collapse;font-size:12px;margin:0.5em 0}td,th{border:1px solid
#ccc;padding:3px 6px;text-align:right;vertical-align:top}th{background:#f0f0f0}
td:first-child{text-align:left}code{background:#f5f5f5;padding:0 3px}img{max-width:100%}"""


def html_report(markdown: str, images: dict[str, bytes], title: str = "simtest report") -> str:
    """A self-contained HTML page from the report's Markdown (markdown-it-py, figures inlined).

    Parameters
    ----------
    markdown : str
        The ``report.md`` text; images referenced as ``figures/<name>``.
    images : dict of str to bytes
        PNG bytes by file name.
    title : str
        Page title.

    Returns
    -------
    str
        HTML5 with every ``figures/<name>`` image replaced by a ``data:image/png;base64`` URI
        (an image missing from ``images`` keeps its relative link).
    """
    md = MarkdownIt("commonmark").enable("table")
    tokens = md.parse(markdown)
    for tok in tokens:
        for ch in tok.children or []:
            if ch.type == "image":
                src = str(ch.attrGet("src") or "")
                name = src.rsplit("/", 1)[-1]
                if src.startswith("figures/") and name in images:
                    b64 = base64.b64encode(images[name]).decode("ascii")
                    ch.attrSet("src", f"data:image/png;base64,{b64}")
    body = md.renderer.render(tokens, md.options, {})
    return ("<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>"
            f"{html.escape(title)}</title><style>{_CSS}</style></head><body>\n{body}</body></html>\n")
