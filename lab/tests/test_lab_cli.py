"""`python -m lab` refuses a page it cannot update and a folder with no runs in one line, exit 2, before any
table is drawn (before, 2026-12-06: --update of a missing page ended in a FileNotFoundError traceback after the
statistics; `stalls` of a mistyped folder wrote nothing and said nothing, exit 0)."""

from __future__ import annotations

from lab.__main__ import main


def test_a_missing_page_and_a_folder_without_runs_are_refused(tmp_path, capsys):
    assert main(["report", "--update", str(tmp_path / "missing.md")]) == 2
    assert capsys.readouterr().err == (f"error: --update {tmp_path / 'missing.md'}: no such markdown file (the page "
                                       "whose marked blocks get the tables)\n")
    assert main(["stalls", str(tmp_path)]) == 2
    assert capsys.readouterr().err == (f"error: {tmp_path} holds no runs/ folder (a grid folder, e.g. "
                                       "lab/results/curriculum)\n")
