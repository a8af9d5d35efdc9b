"""`python -m experiments run` refuses a number it cannot train with in one line, exit 2, before any run starts
(before, 2026-12-06: a ThreadPoolExecutor traceback for --jobs 0; --seeds -1 and --episodes 0 started every run only
for each to fail)."""

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
