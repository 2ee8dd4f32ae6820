"""The README's "What the testbed shows so far" section, generated from the committed reports.

Every number of that section is read from a committed ``results.json`` (the latest run folder of
each suite under ``reports/`` whose name does not end in ``-local``), so the section cannot drift
from the reports; ``tests/test_readme.py`` fails when the README's copy is stale.

Run ``python -m simtest.harness.readme`` to rewrite the section in place (between its two marker
lines), ``--check`` to exit 1 when it is stale. ``python -m simtest.harness.regenerate``
re-runs the committed suites first, then calls this.
"""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
from pathlib import Path

from simtest._io import atomic_write_text
from simtest.harness.claims import best_marks
from simtest.harness.report.document import BEST_RULE, fmt
from simtest.resources import data_root

__all__ = ["BEGIN", "END", "committed_runs", "section_text", "replace_section", "main"]

BEGIN = ("<!-- BEGIN what-the-testbed-shows: generated from the committed reports by "
         "`python -m simtest.harness.readme`; edits here are overwritten -->")
END = "<!-- END what-the-testbed-shows -->"

_VERDICT = {True: "holds", False: "does not hold", None: "undecided"}


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
        name (run ids are dates or UTC times), sorted by suite name.
    """
    out = []
    root = Path(reports)
    for suite in sorted(p for p in root.iterdir() if p.is_dir()) if root.is_dir() else []:
        runs = sorted(p for p in suite.iterdir() if p.is_dir() and not p.name.endswith("-local")
                      and not p.name.startswith(".") and (p / "results.json").is_file())
        if runs:
            out.append(runs[-1])
    return out


def _esc(t) -> str:
    return str(t).replace("|", "\\|").replace("\n", " ")


def _run_block(folder: Path, rel: str) -> list[str]:
    r = json.loads((folder / "results.json").read_text(encoding="utf-8"))
    s, p = r["suite"], r["provenance"]
    n_unique = len({c["key"] for c in r["cases"]})
    real = sum(v["realisations"] for v in p["realisations_per_s"].values())
    commit = (p.get("git_commit") or "?")[:10]
    clean = {True: "uncommitted changes", False: "clean", None: "no git"}[p.get("git_dirty")]
    L = [f"**`{rel}`** (suite `{s['name']}`, run `{r['run_id']}`): {len(r['sweeps'])} sweeps, "
         f"{len(r['cases'])} cases ({n_unique} distinct settings), {real} realisations; commit "
         f"`{commit}` ({clean}); wall time {p['wall_time_s']:.0f} s with {p['workers']} "
         f"worker(s) on {p['machine']['cpu_count']} CPUs. Report: `{rel}/report.html`.", ""]
    if r.get("schema_version", 1) < 2:
        L += ["Schema 1 results (no summary table or verdicts yet: regenerate them with "
              "`python -m simtest.harness.regenerate`). The paper's claims, sweep by sweep:", ""]
        for sw in r["sweeps"]:
            for c in sw.get("comparison") or []:
                L.append(f"- `{sw['name']}`: {_esc((sw.get('paper') or {}).get('claim', ''))}: "
                         f"**{_VERDICT[c['holds']]}** ({c['estimator']}: {c['ours']}).")
        return L + [""]
    ests = s["estimators"]
    fams = r.get("families", {})
    if fams:
        L += ["| family | " + " | ".join(ests) + " | false positives per image |",
              "|---" * (len(ests) + 2) + "|"]
        for fam, f in fams.items():
            meds = {e: f["estimators"][e].get("median") for e in ests}
            marks = best_marks({e: f["estimators"].get(e) for e in ests})
            cells = [("-" if v is None else f"**{fmt(v)}**" if marks.get(e) == "best"
                      else f"{fmt(v)} (tie)" if marks.get(e) == "tie" else fmt(v))
                     for e, v in meds.items()]
            fp = fmt(f.get("false_positives_per_image")) if f.get("false_positives") is not None \
                else "n/a"
            L.append(f"| {_esc(fam)} | " + " | ".join(cells) + f" | {fp} |")
        # wrapped: the README keeps every line under 300 characters
        L += ["", *textwrap.wrap("Median normal error (deg) pooled over each family's cases. "
                                 + BEST_RULE, 100, break_long_words=False,
                                 break_on_hyphens=False), ""]
    for c in r.get("claims", []):
        L.append(f"- {_esc(c['claim'])}: **{_VERDICT[c['holds']]}** ({c['source']}; "
                 f"{c['measured']}).")
    if r.get("claims"):
        L.append("")
    return L


def section_text(reports: str | Path | None = None, repo: str | Path | None = None) -> str:
    """The generated section (marker lines included).

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
    L = [BEGIN, "", "From the committed reports (every number below is read from their "
                    "`results.json`; the reports give the details and the figures):", ""]
    runs = committed_runs(reports)
    if not runs:
        L += ["No committed report yet: run `python -m simtest.harness.regenerate`.", ""]
    for folder in runs:
        try:
            rel = folder.resolve().relative_to(repo.resolve()).as_posix()
        except ValueError:
            rel = folder.as_posix()
        L += _run_block(folder, rel)
    L.append(END)
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
    ap = argparse.ArgumentParser(prog="python -m simtest.harness.readme",
                                 description=__doc__.splitlines()[0])
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
    print(f"{a.readme}: section 'What the testbed shows so far' "
          f"{'rewritten' if new != text else 'already fresh'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
