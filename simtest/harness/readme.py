"""The README's "What the testbed shows so far" section, generated from the committed reports.

Every number is read from the latest committed ``results.json`` of each suite under ``reports/``
(run folders not ending in ``-local``); ``tests/test_readme.py`` fails when the README's copy is
stale. ``python -m simtest.harness.readme`` rewrites it in place, ``--check`` exits 1 when stale.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from simtest._io import atomic_write_text
from simtest.decisions import data_side
from simtest.harness.claims import best_marks
from simtest.harness.report.document import lobe_cell
from simtest.harness.report.numbers import esc, fmt
from simtest.reconstruct.registry import get, names
from simtest.resources import data_root

__all__ = ["BEGIN", "END", "committed_runs", "section_text", "replace_section", "main"]

BEGIN = ("<!-- BEGIN what-the-testbed-shows: generated from the committed reports by "
         "`python -m simtest.harness.readme`; edits here are overwritten -->")
END = "<!-- END what-the-testbed-shows -->"

def committed_runs(reports: str | Path) -> list[Path]:
    """The latest committed run folder of each suite under ``reports``.

    Parameters
    ----------
    reports : str or Path
        The reports root (``reports/``).

    Returns
    -------
    list of Path
        One ``<reports>/<suite>/<run id>`` per suite that has a run folder holding a
        ``results.json`` and not ending in ``-local`` (local runs are git-ignored), the latest by
        name (run ids are dates or UTC times), sorted by suite name; folders of other commands'
        reports (results without a ``suite``) are passed over.
    """
    out = []
    root = Path(reports)
    for suite in sorted(p for p in root.iterdir() if p.is_dir()) if root.is_dir() else []:
        runs = sorted(p for p in suite.iterdir() if p.is_dir() and not p.name.endswith("-local")
                      and not p.name.startswith(".") and (p / "results.json").is_file())
        if runs and _is_suite_run(runs[-1]):
            out.append(runs[-1])
    return out


def _is_suite_run(folder: Path) -> bool:
    """A validation suite's run (its results name their suite), not another command's report."""
    try:
        return "suite" in json.loads((folder / "results.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False


#: estimators that are baselines or oracles, never "the best other" of a row
_NOT_OTHERS = frozenset(name for name in names() if get(name).reference)


#: The least share of a family's scored highlights an estimator's median must rest on to stand as
#: "the other estimator with the lowest median" (a presentation rule, not tuned on any result).
MIN_SHARE_OF_HIGHLIGHTS = 0.5


def _rows(folder: Path, rel: str) -> list[str]:
    r = json.loads((folder / "results.json").read_text(encoding="utf-8"))
    ests = r["suite"]["estimators"]
    out = []
    for fam, f in r.get("families", {}).items():
        st = f["estimators"]
        med = {e: st[e].get("median") for e in ests}
        n = {e: st[e].get("n_ok") for e in ests}
        marks = best_marks({e: st.get(e) for e in ests})  # over every estimator, shown or not

        def cell(e):
            if med.get(e) is None:
                return "-"
            text = f"{fmt(med[e])} (n {n[e]})"
            return f"**{text}**" if marks.get(e) == "best" else text
        most = max((v for v in n.values() if v), default=0)
        others = [(med[e], e) for e in ests if e not in _NOT_OTHERS and med[e] is not None
                  and n[e] >= MIN_SHARE_OF_HIGHLIGHTS * most]
        best = min(others) if others else None
        e = f.get("end_to_end")
        e2e = ("- ¹ | - | -" if f.get("protocol") == "paper" else "- ² | - | -") if not e else (
            f"{100 * e['within_1deg']:.3g} / {100 * e['within_5deg']:.3g} % (n {e['n']}) | "
            f"{fmt(e['median_ok_deg']) if e['n_ok'] else '-'} (n {e['n_ok']}) | {fmt(e['false_ok_per_frame'])}; {lobe_cell(e)}")
        side = "held out" if data_side(r["suite"]["seed"]) == "held_out" else "tuning"
        out.append(f"| [{r['suite']['name']}]({rel}/report.md), seed {r['suite']['seed']} ({side}) | "
                   f"{esc(fam)} | {e2e} | "
                   f"{cell('recommended') if 'recommended' in ests else '- ¹'} | {cell('bp_ray')} | "
                   + ("-" if best is None else f"`{best[1]}` {cell(best[1])}") + " |")
    return out


def section_text(reports: str | Path | None = None, repo: str | Path | None = None) -> str:
    """The generated section (marker lines included): one table of the committed reports.

    One row per family of each committed report: median normal errors (deg, with n) of the
    recommended normal, of ``bp_ray`` and of the other estimator with the lowest median among those
    scored on at least :data:`MIN_SHARE_OF_HIGHLIGHTS` of the row's highlights, in bold where
    :func:`simtest.harness.claims.best_marks` calls it best.

    Parameters
    ----------
    reports : str or Path, optional
        The reports root; default ``<repo>/reports``.
    repo : str or Path, optional
        The root that paths in the text are relative to; default :func:`simtest.resources.data_root`.

    Returns
    -------
    str
        Markdown, ending with a newline.
    """
    repo = Path(repo) if repo is not None else data_root()
    reports = Path(reports) if reports is not None else repo / "reports"
    L = [BEGIN, ""]
    runs = committed_runs(reports)
    if not runs:
        return "\n".join(L + ["No committed report yet: run `python -m simtest.harness.regenerate`.", "", END]) + "\n"
    L += ["| report | family | end to end: within 1 / 5 deg | median ok | false ok; ok on a lobe, per frame "
          "| given the highlight: recommended | bp_ray | other estimator with the lowest median |", "|---" * 8 + "|"]
    for folder in runs:
        try:
            rel = folder.resolve().relative_to(repo.resolve()).as_posix()
        except ValueError:
            rel = folder.as_posix()
        L += _rows(folder, rel)
    L += ["", f"From the {len(runs)} committed runs linked in the rows (`reports/<suite>/<run>/`). Seeds: tuning "
          "or held out (`simtest/decisions.py`).",
          "End to end: `simtest render`, then `simtest reconstruct frame.png --intrinsics camera.json -o OUT` "
          "(defaults), per true highlight: share with a recommended normal within 1 / 5 deg, median error "
          "if ok; per frame: false ok (no highlight or lobe near), ok on a lobe with no exact BP (median error).",
          "Given the highlight (never what "
          "a user gets): median error of `bp_ray`, the light-aware fits and `recommended` on every "
          "matched true highlight, whatever its status (the isophote estimators where ok).",
          "In bold: a median below every other estimator's of its row (shown or not) by more than "
          "the 95 % confidence interval", "of the difference (the reports' rule); none where the "
          "lowest cannot be told apart from another. Other estimators count where scored on at "
          f"least {MIN_SHARE_OF_HIGHLIGHTS:.0%} of the row's highlights.",
          "¹ No recommended normal: suites of the paper's protocol (co-located light) score the estimators alone."
          + (" ² Run before the end-to-end records: to regenerate." if any("- ² |" in x for x in L) else ""), "", END]
    return "\n".join(L) + "\n"


def replace_section(readme_text: str, section: str) -> str:
    """``readme_text`` with the generated section replaced (or inserted).

    Parameters
    ----------
    readme_text : str
        The README.
    section : str
        From :func:`section_text`.

    Returns
    -------
    str
        The text between (and including) the markers replaced; without markers, the section is
        put right after the ``## What the testbed shows so far`` heading, replacing the prose up
        to the next ``## `` heading.

    Raises
    ------
    ValueError
        If the README has neither the markers nor that heading.
    """
    if BEGIN in readme_text and END in readme_text:
        a = readme_text.index(BEGIN)
        b = readme_text.index(END) + len(END)
        return readme_text[:a] + section.rstrip("\n") + readme_text[b:]
    head = "## What the testbed shows so far\n"
    if head not in readme_text:
        raise ValueError(f"README: no '{head.strip()}' heading and no generated-section markers")
    a = readme_text.index(head) + len(head)
    nxt = readme_text.find("\n## ", a)
    b = len(readme_text) if nxt < 0 else nxt + 1
    return readme_text[:a] + "\n" + section + "\n" + readme_text[b:]


def main(argv: list[str] | None = None) -> int:
    """``python -m simtest.harness.readme [--check] [--readme PATH] [--reports DIR]``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        0 when written (or fresh with ``--check``), 1 when ``--check`` finds it stale, 2 on a
        README without the section (one line on stderr).
    """
    ap = argparse.ArgumentParser(prog="python -m simtest.harness.readme", description=__doc__.splitlines()[0])
    ap.add_argument("--readme", type=Path, default=data_root() / "README.md")
    ap.add_argument("--reports", type=Path, default=None)
    ap.add_argument("--check", action="store_true", help="exit 1 if the section is stale")
    a = ap.parse_args(argv)
    try:
        text = a.readme.read_text(encoding="utf-8")
        new = replace_section(text, section_text(a.reports, repo=a.readme.parent))
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if a.check:
        if new != text:
            print(f"{a.readme}: the section 'What the testbed shows so far' is stale; run "
                  "`python -m simtest.harness.readme`", file=sys.stderr)
            return 1
        return 0
    if new != text:
        atomic_write_text(a.readme, new)
    print(f"{a.readme}: section 'What the testbed shows so far' {'rewritten' if new != text else 'already fresh'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
