"""The README's "What the testbed shows so far" is generated from the committed reports."""

from __future__ import annotations

import json
import shutil

import pytest

from simtest.harness.readme import (BEGIN, END, committed_runs, main, replace_section,
                                    section_text)
from simtest.resources import data_root

ROOT = data_root()


def test_readme_section_matches_the_committed_reports():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert BEGIN in text and END in text
    assert replace_section(text, section_text()) == text, (
        "README.md is stale: run `python -m simtest.harness.readme` (or "
        "`python -m simtest.harness.regenerate` to re-run the suites first)")


def test_a_changed_result_makes_the_section_stale(tmp_path):
    src = committed_runs(ROOT / "reports")[0]
    dst = tmp_path / "reports" / src.parent.name / src.name
    shutil.copytree(src, dst)
    readme = tmp_path / "README.md"
    readme.write_text("# x\n\n## What the testbed shows so far\n\nold prose\n\n## Next\n")
    assert main(["--readme", str(readme), "--reports", str(tmp_path / "reports")]) == 0
    assert "old prose" not in readme.read_text() and "## Next" in readme.read_text()
    assert main(["--readme", str(readme), "--reports", str(tmp_path / "reports"),
                 "--check"]) == 0
    r = json.loads((dst / "results.json").read_text())
    fam = next(iter(r["families"].values()))
    est = next(e for e in fam["estimators"].values() if e.get("median") is not None)
    est["median"] *= 2.0  # any number of the section comes from the results
    (dst / "results.json").write_text(json.dumps(r))
    assert main(["--readme", str(readme), "--reports", str(tmp_path / "reports"),
                 "--check"]) == 1


def test_readme_without_the_section_is_one_line(tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text("# nothing here\n")
    assert main(["--readme", str(readme), "--reports", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "What the testbed shows so far" in err[0]


@pytest.mark.parametrize("name", ["paper-figure3", "rendered"])
def test_the_committed_suites_have_reports(name):
    assert name in {p.parent.name for p in committed_runs(ROOT / "reports")}
