"""``simtest evaluate c3vd`` and ``simtest evaluate detection``.

``c3vd`` reconstructs a C3VD-format sequence and scores every estimator against its ground-truth
normals (and the light-aware fits' depths against its depth maps); ``detection`` scores highlight
detection against labelled structures. Each replaces its output folder as a whole; bad input
exits 2 with one line, an unwritable ``OUT`` exits 4 before any work.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Optional

import typer

from simtest import __version__
from simtest.evaluate.c3vd import load_frame, scan_sequence
from simtest.evaluate.operating import precision_recall_figure
from simtest.evaluate.detection import (cross_validated_report, evaluate_frames, groups, is_suite,
                                        labelled_real_frames, labeller_agreement, rendered_frames, suite_frames)
from simtest.evaluate.figures import detection_figure, reliability_figure
from simtest.evaluate.report import SCHEMA, SCHEMA_VERSION, render_html
from simtest.evaluate.score import score_highlights, summarise, summarise_depth
from simtest.geometry.camera_file import load_camera
from simtest.geometry.response import ResponseError
from simtest.harness.report.figures import figure_png
from simtest._exit import BAD_INPUT, fail
from simtest._progress import transient_progress
from simtest._outdir import check_out_folder, write_out_folder
from simtest.reconstruct.cli import check_workers, option_message, reconstruct_single
from simtest.reconstruct.io import estimate_to_dict
from simtest.reconstruct.settings import ReconSettings

#: ``simtest reconstruct``'s defaults for whole frames, which ``evaluate`` uses too
FRAME_DEFAULTS = ReconSettings.for_frames()
from simtest.reconstruct.view3d import render_view, surface_from_depth

#: What ``evaluate c3vd`` writes in OUT (fnmatch patterns; nothing else may be there).
OUTPUT_FILES = ("results.json", "report.html", "view_*.png")

#: ``--workers`` of both commands: the light-aware fits' processes (the results do not depend on it).
WORKERS_OPTION = typer.Option(0, "--workers", "-j", min=0, show_default=False, help="Worker processes for each "
                              "frame's light-aware fits (0, the default: one per core; at most the CPU count).")
evaluate_app = typer.Typer(help="Score reconstructions against datasets with ground-truth normals.", no_args_is_help=True)


@evaluate_app.command("c3vd")
def c3vd_command(
    seq_dir: Path = typer.Argument(..., help="Sequence folder in C3VD's layout (NNNN_color.png, NNNN_normals.tiff, ...).",
                                   show_default=False),
    intrinsics: Path = typer.Option(..., "--intrinsics", "-k", help="Camera file of the sequence (C3VD: omnidirectional)."),
    out: Path = typer.Option(..., "--out", "-o", show_default=False,
                             help="Output folder, new, empty or a previous run's (replaced as a whole): "
                             "results.json, report.html, view_NNNN.png (--views)."),
    isovalue: list[float] = typer.Option(list(FRAME_DEFAULTS.isovalues), "--isovalue", "-t",
                                         help="Isovalue(s) t in (0, 1); repeat for nested isophotes (reconstruct's default)."),
    normalise: str = typer.Option(FRAME_DEFAULTS.normalise.value,
                                  help="Intensity normalisation: auto, bp, full_scale or local (reconstruct's default)."),
    smooth_sigma_px: Optional[float] = typer.Option(  # noqa: UP045 (typer reads Optional)
        None, "--smooth", help="Gaussian smoothing sigma in px before detection (default: from the image's noise, as "
        "reconstruct).", show_default=False),
    detection: str = typer.Option(FRAME_DEFAULTS.detection, help="Candidate detection: local_peak or full_scale "
                                  "(reconstruct's default)."),
    max_frames: int = typer.Option(0, "--max-frames", help="Evaluate only the first N frames (0: all).", min=0),
    views: int = typer.Option(0, "--views", help="Also write OUT/view_NNNN.png, a 3D view (estimates beside the GT "
                              "surface from depth), for the first N frames with a reconstructed highlight.", min=0),
    workers: int = WORKERS_OPTION,
) -> None:
    """Reconstruct every frame of SEQ_DIR and score every estimator against the ground truth:
    the normals, and with a light rig in the camera file the light-aware fits' depth against
    NNNN_depth.tiff (relative error).

    Writes, in the folder OUT (replaced as a whole): OUT/results.json (every highlight's errors and
    the summaries), OUT/report.html and with --views N OUT/view_NNNN.png (a 3D view of frame NNNN).
    Exit status 2: bad input; 4: OUT cannot be written.
    """
    workers = check_workers(workers) or os.cpu_count() or 1
    target = check_out_folder(out, OUTPUT_FILES)
    try:
        camera_file = load_camera(intrinsics)
        camera = camera_file.model
        frames = scan_sequence(seq_dir)[:max_frames or None]  # --max-frames 0: all
        settings = ReconSettings.for_frames(isovalues=isovalue, normalise=normalise,
                                            smooth_sigma_px=smooth_sigma_px, detection=detection)
        rows: list[dict] = []
        n_cand = 0
        view_inputs: list[tuple[str, list, object]] = []
        with transient_progress() as progress:
            task = progress.add_task("reconstructing frames", total=len(frames))
            for fr in frames:
                img, truth = load_frame(fr, camera)
                try:  # as `simtest reconstruct FRAME -k CAMERA_FILE` (its rig and response) does
                    ests = reconstruct_single(img, camera_file, settings, workers=workers)[0]
                except ResponseError as exc:  # a frame the response could not have written: name both
                    raise ResponseError(f"{intrinsics}: {exc} (frame {fr.index})") from None
                n_cand += len(ests)
                rows.extend(score_highlights(fr.index, ests, truth, camera))
                if len(view_inputs) < views and any(e.ok for e in ests):
                    tp = None if truth.depth_mm is None else surface_from_depth(truth.depth_mm, camera)
                    view_inputs.append((fr.index, [estimate_to_dict(e) for e in ests], tp))
                progress.advance(task)
        results = {
            "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "simtest_version": __version__,
            "sequence": str(seq_dir), "camera": camera.to_json_dict(), "settings": settings.to_dict(),
            "n_frames": len(frames), "n_highlights": n_cand,
            "n_ok": sum(r["status"] == "ok" for r in rows), "n_scored": sum(r["scored"] for r in rows),
            "estimators": summarise(rows, "errors_bp_deg"),
            "estimators_footprint": summarise(rows, "errors_footprint_deg"),
            "depth": summarise_depth(rows) if any(fr.depth is not None for fr in frames) else None,
            "highlights": rows,
        }
        text = json.dumps(results, indent=1, allow_nan=False) + "\n"
        page = render_html(results)
    except (ValueError, OSError, ImportError) as exc:  # C3VDError, CameraFileError, settings: ValueErrors
        fail(option_message(exc), BAD_INPUT)

    def fill(folder: Path) -> None:
        (folder / "results.json").write_text(text, encoding="ascii")
        (folder / "report.html").write_text(page, encoding="utf-8")
        for idx, specs, tp in view_inputs:
            render_view(folder / f"view_{idx}.png", specs, truth_points=tp)

    write_out_folder(out, target, fill, OUTPUT_FILES)
    med = results["estimators"]
    summary = ", ".join(f"{k} {v['median_deg']:.2f}" for k, v in med.items() if v["median_deg"] is not None)
    typer.echo(f"{len(frames)} frame(s), {results['n_highlights']} candidate(s), {results['n_ok']} ok, "
               f"{results['n_scored']} scored; median error (deg) at the BP: {summary or 'none'}")
    if results["depth"]:
        typer.echo("median |relative depth error|: " + ", ".join(
            f"{k} {100 * v['median_abs']:.1f} % (n = {v['n']})" for k, v in results["depth"].items()))
    typer.echo(f"-> {out / 'results.json'}, {out / 'report.html'}")


#: What ``evaluate detection`` writes in OUT (nothing else may be there).
DETECTION_FILES = ("results.json", "report.md", "detection.png", "reliability.png", "precision_recall.png")


@evaluate_app.command("detection")
def detection_command(
    source: str = typer.Argument(..., help="A labelled set of real frames (JSON, e.g. tests/data/real/"
                                 "structures_labelled.json), an endoscope scene (name or TOML) whose render "
                                 "labels its targets, or a rendered suite (name, e.g. endoscope, or TOML): "
                                 "every case's renders.", show_default=False),
    out: Path = typer.Option(..., "--out", "-o", show_default=False,
                             help="Output folder, new, empty or a previous run's (replaced as a whole): "
                             "results.json, report.md, detection.png, reliability.png, precision_recall.png."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, help="Render seed (a scene; default the scene's)."),  # noqa: UP045
    realisations: Optional[int] = typer.Option(  # noqa: UP045
        None, "--realisations", "-n", min=1, help="Renders per setting (a suite; default the suite's)."),
    light_aware: bool = typer.Option(True, "--light-aware/--detection-only", help="A render: what `simtest "
                                     "reconstruct -k camera.json` gives it (response, rig, light-aware fits and "
                                     "their normals), or the detection alone (faster)."),
    workers: int = WORKERS_OPTION,
) -> None:
    """Score highlight detection: precision, recall and F1 of the candidates and of the "ok"
    estimates against labelled isolated highlights, per frame and pooled, with reconstruct's
    defaults (a render: with its camera file, as `simtest reconstruct -k camera.json` runs).

    Writes, in the folder OUT (replaced as a whole): OUT/results.json (counts, scores and where each
    candidate fell), OUT/report.md, OUT/detection.png (hits, false positives and misses),
    OUT/reliability.png (the confidence's reliability diagram) and OUT/precision_recall.png. Exit
    status 2: bad input; 4: OUT cannot be written.
    """
    target, workers = check_out_folder(out, DETECTION_FILES), check_workers(workers) or os.cpu_count() or 1
    if Path(source).suffix.lower() not in ("", ".json", ".toml"):  # an image or another file
        fail(f"{source}: not a labelled set (.json), a scene or a suite (.toml or a bundled name)", BAD_INPUT)
    kept: list = []  # each frame's estimates, for the confidence's cross-validation
    try:
        with transient_progress() as progress:
            if source.endswith(".json"):
                frames = labelled_real_frames(source)
            elif is_suite(source):
                task = progress.add_task(f"rendering {source}", total=None)
                frames = suite_frames(source, realisations=realisations,
                                      progress=lambda done, total: progress.update(task, completed=done, total=total))
            else:
                frames = rendered_frames(source, seed=seed)
            task = progress.add_task(f"reconstructing {len(frames)} frame(s)", total=len(frames))
            results = evaluate_frames(frames, keep=kept, light_aware=light_aware, workers=workers,
                                      progress=lambda done, total: progress.update(task, completed=done))
        results = {"schema": "simtest.evaluate.detection", "schema_version": 1,
                   "simtest_version": __version__, "source": source} | results
        if source.endswith(".json"):
            results["labeller_agreement"] = labeller_agreement(source)
            results["confidence_cross_validated"] = cross_validated_report(frames, verified=kept)
        if any("@" in f["name"] for f in results["frames"]):
            results["groups"] = groups(results["frames"])
        text = json.dumps(results, indent=1, allow_nan=False) + "\n"
        md = _detection_markdown(results)
        pngs = {"detection.png": figure_png(detection_figure(frames, results)),
                "reliability.png": figure_png(reliability_figure(results)),
                "precision_recall.png": figure_png(precision_recall_figure(
                    results["precision_recall"], default=results.get("default_min_confidence")))}
    except (ValueError, OSError, ImportError) as exc:
        fail(exc, BAD_INPUT)

    def fill(folder: Path) -> None:
        for name, data in ({"results.json": text.encode("ascii"), "report.md": md.encode("utf-8")} | pngs).items():
            (folder / name).write_bytes(data)

    write_out_folder(out, target, fill, DETECTION_FILES)
    p = results["pooled"]
    typer.echo(f"{len(frames)} frame(s), {p['targets']} target(s): ok precision {_fmt(p['precision_ok'])}, "
               f"recall {_fmt(p['recall_ok'])}; candidates precision {_fmt(p['precision_candidates'])}, "
               f"recall {_fmt(p['recall_candidates'])} -> {out / 'report.md'}")


def _fmt(v) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def _detection_markdown(results: dict) -> str:
    p = results["pooled"]
    L = [f"# Highlight detection: {results['source']}", "",
         "Targets are the labelled isolated specular highlights; a candidate or an ok estimate is a "
         "true positive when it is the first to fall on a target (a rendered target that gathers k "
         "lights' highlights: one of the first k; see simtest.evaluate.detection). Renders are "
         + ("reconstructed as simtest reconstruct does with their camera file (response, light rig, light-aware "
            "fits). " if results.get("light_aware") else
            "detected and checked under their light rig, without the light-aware fits (`--detection-only`; "
            "the fits can turn a rig partner's row ok in simtest reconstruct). ")
         + "On a render, a candidate on no target falls on `specular` where "
         "its light is mostly specular reflection (a glint that is not an isolated highlight), else on "
         "`unlabelled`.", ""]
    head = ["| {} | targets | candidates | precision | recall | ok | ok precision | ok recall | ok F1 | "
            "not examined |", "|---|---|---|---|---|---|---|---|---|---|"]

    def row(f: dict) -> str:
        return (f"| {f['name']} | {f['targets']} | {f['candidates']} | {_fmt(f['precision_candidates'])} | "
                f"{_fmt(f['recall_candidates'])} | {f['ok']} | {_fmt(f['precision_ok'])} | "
                f"{_fmt(f['recall_ok'])} | {_fmt(f['f1_ok'])} | {f['not_examined']} |")

    def bin_row(r: dict) -> str:  # a reliability bin's cells
        return (f"[{r['bin'][0]:.1f}, {r['bin'][1]:.1f}) | {r['n']} | {_fmt(r['mean_confidence'])} | "
                f"{_fmt(r['fraction_true'])} |")
    if results.get("groups"):
        L += ["Pooled per sweep (its frames are named sweep@value#realisation below):", "",
              head[0].format("sweep"), head[1]]
        for g in results["groups"]:
            n = sum(x["not_examined"] for x in results["frames"] if x["name"].split("@", 1)[0] == g["name"])
            L.append(row(g | {"name": f"{g['name']} ({g['frames']} frames)", "not_examined": n}))
        L.append("")
    L += [head[0].format("frame"), head[1]]
    L += [row(f) for f in results["frames"] + [p | {"not_examined": sum(x["not_examined"] for x in results["frames"])}]]
    agree = results.get("labeller_agreement")
    if agree:
        a, b, c = agree["pass2_vs_pass1"], agree["pass2_vs_resolved"], agree["pass1_vs_resolved"]
        L += ["", f"How far the labellers agree on the targets (a ceiling for any detector scored against "
              f"these labels): the second pass's isolated highlights scored against the first's have "
              f"precision {_fmt(a['precision'])} and recall {_fmt(a['recall'])}. Against the resolved "
              f"labels, the first pass has precision {_fmt(c['precision'])} and recall "
              f"{_fmt(c['recall'])}, the second precision {_fmt(b['precision'])} and recall "
              f"{_fmt(b['recall'])}: each labeller, read as a detector, beside the ok row above."]
    L += ["", "What the ok estimates fall on (pooled): "
          + ", ".join(f"{k} {v}" for k, v in p["ok_on"].items()) + ".", "",
          "Status of every candidate: " + ", ".join(f"{k} {v}" for k, v in results["statuses"].items())
          + " (reasons in simtest.reconstruct.failures.REASONS).", "",
          "The targets no ok estimate found (pooled), by the status of the first candidate on them: "
          + (", ".join(f"{k} {v}" for k, v in results.get("missed_by", {}).items()) or "none") + ".", ""]
    if results.get("normal_error_deg"):
        how = ("(with the light-aware fits, as `simtest reconstruct` with the camera file)"
               if results.get("light_aware") else "(without the light-aware fits: `--detection-only`)")
        L += [f"The ok estimates' recommended normals {how} against the render's true normal "
              "at the BP (its shading normal, with the micro-relief where the scene has one), by what they fall on:", "",
              "| on | n | median error (deg) | 90th percentile (deg) |", "|---|---|---|---|"]
        L += [f"| {on} | {e['n']} | {e['median']:.2f} | {e['p90']:.2f} |"
              for on, e in results["normal_error_deg"].items()]
        L.append("")
    if rank := results.get("confidence_vs_error"):
        L += [f"Confidence against the normal's error over these ok estimates: Spearman's rho {rank['rho']:+.2f} "
              f"(n {rank['n']}, p {rank['p']:.2g}; positive: the more confident, the larger the error). The "
              "confidence ranks what a candidate is (an isolated highlight), not how accurate its normal is.", ""]
    L += [
          "![hits, false positives and misses](detection.png)", "", "## Confidence", "",
          "Reliability of each candidate's confidence (simtest.reconstruct.verify.confidence): per bin, "
          "the fraction of candidates that are a target's first match.", "",
          "| candidates | bin | n | mean confidence | fraction targets |", "|---|---|---|---|---|"]
    L += [f"| {key} | {bin_row(r)}" for key in ("candidates", "ok") for r in results["reliability"][key]]
    cv = results.get("confidence_cross_validated")
    if cv:
        L += ["", f"Leave one frame out (the confidence a new frame can expect, on the {cv['n']} fits "
              f"that pass the checks): ranking AUC {_fmt(cv['auc'])} (0.5: no better than chance).", "",
              "| bin | n | mean confidence | fraction targets |", "|---|---|---|---|"]
        L += [f"| {bin_row(r)}" for r in cv["reliability"]]
    L += ["", "![reliability diagram](reliability.png)", "", "## Operating point", "",
          "Precision and recall of the fits that pass the checks kept by `simtest reconstruct "
          "--min-confidence C` (read off this run's matches; this run's default C: "
          f"{_fmt(results.get('default_min_confidence'))}, simtest.decisions.DEFAULT_MIN_CONFIDENCE "
          "on a colour frame without a rig of separate lights, else MIN_CONFIDENCE_UNMODELLED).",
          "", "| min confidence | ok kept | precision | recall |", "|---|---|---|---|"]
    d = results.get("default_min_confidence")
    for i, r in enumerate(results["precision_recall"]):  # every other row, and the default's
        mark = " (default)" if d is not None and abs(r["min_confidence"] - d) < 1e-9 else ""
        if i % 2 == 0 or mark:
            L.append(f"| {r['min_confidence']:.2f}{mark} | {r['kept']} | {_fmt(r['precision'])} | {_fmt(r['recall'])} |")
    L += ["", "![precision against recall](precision_recall.png)", ""]
    return "\n".join(L)
