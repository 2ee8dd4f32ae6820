"""Reports of a suite run: ``results.json``, ``results.csv``, ``report.md``, ``report.html``.

``<out>/<suite>/<run id>/`` holds them and ``figures/*.png``; the set is written to a temporary
folder beside the run folder and renamed into place, so a reader never sees half a report.
"""

from __future__ import annotations

import json
from pathlib import Path

from simtest._io import replace_output_folder
from simtest.harness.claims import CLAIMS, PAPER_CHECKS, evaluate_claims, evaluate_paper_claim
from simtest.harness.report.document import html_report, markdown_report
from simtest.harness.report.figures import figure_png, make_figures
from simtest.harness.report.provenance import make_run_id, provenance
from simtest.harness.report.results import SCHEMA, SCHEMA_VERSION, build_results, results_csv

#: What a run folder holds (and all it may hold: it is replaced as a whole, never merged).
REPORT_FILES = ("results.json", "results.csv", "report.md", "report.html", "figures/*.png")

__all__ = ["SCHEMA", "SCHEMA_VERSION", "PAPER_CHECKS", "CLAIMS", "REPORT_FILES", "build_results", "write_report",
           "write_report_files", "provenance", "evaluate_paper_claim", "evaluate_claims", "make_run_id", "results_csv"]


def write_report_files(results: dict, folder: str | Path, nightly: dict | None = None,
                       history: list[dict] | None = None) -> Path:
    """Write the report files of a results document into ``folder``, replacing it as a set.

    Parameters
    ----------
    results : dict
        A ``results.json`` document.
    folder : path
        The run folder; an existing one is replaced if it holds only :data:`REPORT_FILES`.
    nightly : dict, optional
        The nightly gate's outcome (:func:`simtest.harness.report.document.markdown_report`).
    history : list of dict, optional
        Nightly history lines, drawn as ``figures/nightly_trend.png``.

    Returns
    -------
    Path
        ``folder``.

    Raises
    ------
    simtest._io.OutputFolderError
        ``folder`` holds files that are not a report's (they are kept; nothing is written).
    """
    folder = Path(folder)
    # the figures and the text first (nothing written yet if one of them fails)
    pngs = {name: figure_png(fig) for name, fig in make_figures(results, history).items()}
    md = markdown_report(results, sorted(pngs), nightly=nightly, history=history)
    html = html_report(md, pngs, title=f"simtest report: {results['suite']['name']}")

    def fill(tmp: Path) -> None:
        (tmp / "figures").mkdir()
        for name, png in pngs.items():
            (tmp / "figures" / name).write_bytes(png)
        (tmp / "results.json").write_text(json.dumps(results, indent=1, allow_nan=False) + "\n", encoding="utf-8")
        (tmp / "results.csv").write_text(results_csv(results), encoding="utf-8")
        (tmp / "report.md").write_text(md, encoding="utf-8")
        (tmp / "report.html").write_text(html, encoding="utf-8")

    # as a set: a failure or a kill leaves the old one whole; a user's file there is never lost
    replace_output_folder(folder, fill, owned=REPORT_FILES)
    return folder


def write_report(run, out_dir: str | Path = "reports", run_id: str | None = None) -> Path:
    """Write ``results.json``, ``results.csv``, ``report.md``, ``report.html`` and figures.

    Parameters
    ----------
    run : simtest.harness.runner.SuiteRun
        The finished run.
    out_dir : path
        Reports root; the files go to ``<out_dir>/<suite name>/<run id>/``.
    run_id : str or None
        Default :func:`make_run_id` (``<UTC time>-local``, ignored by git).

    Returns
    -------
    Path
        The run folder.
    """
    run_id = run_id or make_run_id()
    folder = Path(out_dir) / run.suite.name / run_id
    return write_report_files(build_results(run, run_id), folder)
