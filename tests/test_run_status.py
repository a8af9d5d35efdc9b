"""`python -m cmcl status` (cmcl/run/status.py): one line per run folder, read from its files alone."""

from __future__ import annotations

import json
import os

from cmcl.__main__ import main
from cmcl.io.resume_hint import resume_command
from cmcl.run.runlock import RunLock
from cmcl.run.status import runner_of
from tests.in_process import trained_inline_run
from tests.tiny import make_tiny_config


def trained(path, episodes=8):
    """A finished tiny run of the inline runner (its summary.json written by the command)."""
    return trained_inline_run(make_tiny_config("maddpg", dir=str(path), episodes=episodes))


def status(capsys, *paths) -> tuple[int, list[str]]:
    capsys.readouterr()  # (the training's own lines)
    code = main(["status", *map(str, paths)])
    return code, capsys.readouterr().out.splitlines()


def test_a_finished_a_running_and_a_cut_off_run_each_in_one_line_and_nothing_written(tmp_path, capsys):
    done, held, cut = (trained(tmp_path / name) for name in ("done", "held", "cut"))
    cut.summary_path.unlink()  # killed before its summary: its rows say how far it got
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in tmp_path.rglob("*") if p.is_file()}
    with RunLock.acquire(held.path, "python -m cmcl resume held"):
        code, lines = status(capsys, done.path, held.path, cut.path)
        before |= {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in [held.path / "run.lock"]}
    assert code == 0 and len(lines) == 3, lines
    assert lines[0].startswith(f"{done.path} | inline | its budget done | 8 of 8 episodes | ")
    assert "| last 8 episodes: cov " in lines[0] and lines[0].endswith("| newest checkpoint learner-000001.pt")
    assert lines[1].startswith(f"{held.path} | inline | running (pid {os.getpid()} on ") and "resume:" not in lines[1]
    # without its summary its last checkpoint of the supervisor's counters names the runner, the one `resume` takes
    assert runner_of(cut) == "inline"
    assert lines[2].startswith(f"{cut.path} | inline | cut off (no summary after its last row")
    assert "newest checkpoint learner-000001.pt" in lines[2]
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in tmp_path.rglob("*") if p.is_file()} == before


def test_a_stopped_run_names_its_resume_command_and_a_folder_without_a_run_is_exit_2(tmp_path, capsys):
    run = trained(tmp_path / "stopped", episodes=8)
    summary = json.loads(run.summary_path.read_text())
    summary |= {"ended": "SIGINT", "episodes": 4}
    run.summary_path.write_text(json.dumps(summary))
    (run.path / "config.toml").write_text(run.config_path.read_text().replace("episodes = 8", "episodes = 40"))
    (tmp_path / "other").mkdir()
    code, lines = status(capsys, run.path, tmp_path / "other")
    assert code == 2, lines
    assert "| stopped by SIGINT | 8 of 40 episodes |" in lines[0], lines[0]
    assert lines[0].endswith(f"| resume: {resume_command(run.path)}"), lines[0]
    assert lines[1] == (f"{tmp_path / 'other'} | not a run it can read: {str(tmp_path / 'other')!r} is not a run "
                        "directory (no config.toml)")
