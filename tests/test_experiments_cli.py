"""`python -m experiments` refuses a number it cannot train with, a page it cannot update and a folder with no runs
in one line, exit 2, before any run starts or any table is drawn (before, 2026-12-06: a ThreadPoolExecutor traceback
for --jobs 0; --seeds -1 and --episodes 0 started every run only for each to fail; --update of a missing page ended
in a FileNotFoundError traceback after the statistics; `stalls` of a mistyped folder wrote nothing and said nothing,
exit 0)."""

from __future__ import annotations

import pytest

from experiments.__main__ import main


@pytest.mark.parametrize(("argv", "said"), [
    (["run", "spread", "--jobs", "0", "--seeds", "0"], "error: --jobs must be >= 1 (runs trained at once), got 0"),
    (["run", "spread", "--seeds", "0", "-1"], "error: --seeds must be >= 0 (run.seed), got -1"),
    (["run", "spread", "--episodes", "0", "--seeds", "0"], "error: --episodes must be >= 1, got 0"),
])
def test_a_number_it_cannot_train_with_is_refused_before_any_run(argv, said, tmp_path, capsys):
    assert main([*argv, "--out", str(tmp_path / "grid")]) == 2
    captured = capsys.readouterr()
    assert captured.err == said + "\n" and captured.out == ""
    assert not (tmp_path / "grid").exists()


def test_a_missing_page_and_a_folder_without_runs_are_refused(tmp_path, capsys):
    assert main(["report", "--update", str(tmp_path / "missing.md")]) == 2
    assert capsys.readouterr().err == (f"error: --update {tmp_path / 'missing.md'}: no such markdown file (the page "
                                       "whose marked blocks get the tables)\n")
    assert main(["stalls", str(tmp_path)]) == 2
    assert capsys.readouterr().err == (f"error: {tmp_path} holds no runs/ folder (a grid folder, e.g. "
                                       "bench/results/curriculum)\n")
