"""docs/thesis-data.md's walk through the loop is what scripts/thesis_walk.py writes."""

import runpy
import sys

from conftest import ROOT


def test_thesis_walk_script_reproduces_the_doc(monkeypatch, capsys):
    """Running the script prints the section the doc holds, word for word: the document
    cannot drift from the code. The walk names the certificate first (ball 16 x), then
    plate sag, then ends outside the catalogue with BP112 carrying most of the rest."""
    monkeypatch.setattr(sys, "argv", ["thesis_walk.py", "--print"])
    runpy.run_path(str(ROOT / "scripts" / "thesis_walk.py"), run_name="__main__")
    printed = capsys.readouterr().out.strip()
    assert printed in (ROOT / "docs" / "thesis-data.md").read_text(encoding="utf-8")
    assert "ball 16 x" in printed and "`plate_sag`" in printed
    assert "outside the catalogue" in printed and "BP112" in printed
