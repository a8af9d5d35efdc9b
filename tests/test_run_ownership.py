"""Without Ray: the run directory's lock (one writer), its newest verified policy (either runner), and the stop
signals (first: graceful, second: forced)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from cmcl.io.checkpoint_files import save_torch_atomic
from cmcl.io.verified import VerifiedFile
from cmcl.run.rundir import RunDirectory
from cmcl.run.runlock import LOCK_NAME, RunDirectoryInUse, RunLock
from cmcl.run.stopping import StopSignals


def test_a_second_writer_is_refused_naming_the_holder_and_may_take_over_once_released(tmp_path):
    with RunLock.acquire(tmp_path / "run", "python -m services.launch --config x.toml"):
        with pytest.raises(RunDirectoryInUse, match=rf"in use by pid {os.getpid()} on .*services.launch --config x"):
            RunLock.acquire(tmp_path / "run")
    RunLock.acquire(tmp_path / "run").release()  # released: the next writer gets it


def test_a_lock_left_by_a_killed_process_does_not_block(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from cmcl.run.runlock import RunLock; "
                               f"RunLock.acquire({str(tmp_path)!r}); print('held', flush=True); time.sleep(600)"],
                              stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(RunDirectoryInUse, match=f"pid {holder.pid}"):
        RunLock.acquire(tmp_path)
    holder.kill()
    holder.wait()
    assert json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == holder.pid  # the file stays, nothing holds it
    RunLock.acquire(tmp_path).release()


def policy_state(value: float) -> dict:
    return {"maddpg": {"w": torch.full((2,), value)}, "version": int(value)}


def save_service(run: RunDirectory, value: float) -> None:
    import io

    buffer = io.BytesIO()
    torch.save(policy_state(value), buffer)
    VerifiedFile(run.service_paths()["learner"]).save(buffer.getvalue())


def test_newest_policy_is_the_newest_verified_file_of_either_runner(tmp_path):
    run = RunDirectory(tmp_path)
    assert run.newest_policy() is None
    save_torch_atomic(run.checkpoint_path(500), policy_state(1.0))
    assert run.newest_policy().runner == "inline" and run.newest_policy().path.name == "ckpt_00000500.pt"
    old = time.time() - 60
    os.utime(run.checkpoint_path(500), (old, old))  # written a minute before the service's files below
    save_service(run, 2.0)
    save_service(run, 3.0)
    newest = run.newest_policy()
    assert (newest.runner, newest.path.name, newest.state["version"]) == ("service", "learner-000002.pt", 3)
    newest.path.write_bytes(b"corrupted")  # the newest generation fails its digest: the previous one is used
    fallback = run.newest_policy()
    assert (fallback.runner, fallback.state["version"]) in {("service", 2), ("inline", 1)}
    assert fallback.path.name in {"learner-000001.pt", "ckpt_00000500.pt"}
    assert run.runners() == {"inline", "service"}


def test_first_signal_asks_for_a_stop_and_a_second_forces(tmp_path):
    forced: list[int] = []
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)  # Python's, or SIG_IGN inherited
    with StopSignals(force=forced.append) as stop:
        assert not stop.requested and stop.exit_code == 0
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.requested and stop.name == "SIGTERM" and stop.exit_code == 143 and forced == []
        os.kill(os.getpid(), signal.SIGINT)
        assert forced == [signal.SIGINT] and stop.name == "SIGTERM"  # the first signal decides the exit code
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before  # the previous ones are back


def test_after_training_the_first_signal_exits_at_once():
    forced: list[int] = []
    with StopSignals(force=forced.append) as stop:
        stop.training_over()
        os.kill(os.getpid(), signal.SIGINT)
        assert forced == [signal.SIGINT]


def test_a_torn_last_metrics_line_is_ignored_and_set_aside_and_a_corrupt_one_before_it_refused(tmp_path, capsys):
    """A last line torn by a full disk (EFBIG) made resume and evaluate crash with JSONDecodeError."""
    from cmcl.config import load_config
    from cmcl.run.flags import RunRequest, resumed_config, train_in_run

    run = RunDirectory.create(tmp_path / "run", load_config(None, ("run.episodes=3",)))
    for episode in (1, 2, 3):
        run.log({"kind": "episode", "episodes": episode})
    with run.metrics_path.open("a") as handle:
        handle.write('{"episodes": 4, "kind": "epi')  # the write the full disk cut
    again = RunDirectory.open(run.path)
    config = resumed_config(again, ("run.episodes=5",), RunRequest(runner="inline", resume_dir=str(run.path)))
    assert config.run.episodes == 5 and [r["episodes"] for r in again.rows("episode")] == [1, 2, 3]
    assert capsys.readouterr().err == f"metrics: ignored the torn last line of {run.metrics_path} (line 4)\n"
    again.log({"kind": "episode", "episodes": 4})  # the resumed run appends: the torn line goes aside first
    assert [r["episodes"] for r in again.rows("episode")] == [1, 2, 3, 4]
    assert (run.path / "metrics.jsonl.torn").read_text() == '{"episodes": 4, "kind": "epi\n'
    lines = run.metrics_path.read_text().splitlines()
    run.metrics_path.write_text("\n".join([lines[0], lines[1][:9], *lines[2:]]) + "\n")  # line 2 corrupt
    capsys.readouterr()
    code = train_in_run(RunRequest(runner="inline", resume_dir=str(run.path)), lambda *a: 0)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and f"{run.metrics_path} line 2: not a JSON object" in err, err
    from cmcl.run.evaluate import main as evaluate

    assert evaluate([str(run.path), "--random", "--episodes", "1", "--no-gif"]) == 2, "refused before any work"
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{run.metrics_path} line 2: not a JSON object" in err, err


def test_a_lock_held_by_a_child_of_a_dead_holder_names_the_live_process(tmp_path, monkeypatch):
    """The holder the lock file names has died, but a child that inherited its descriptor (the launcher's Ray
    reaper) still holds the lock: the refusal names that live process, not only the dead pid."""
    from cmcl.run import runlock

    monkeypatch.setattr(runlock, "DEAD_HOLDER_WAIT_S", 0.2)
    script = ("import subprocess, sys; from cmcl.run.runlock import RunLock; lock = RunLock.acquire(sys.argv[1]); "
              "child = subprocess.Popen(['sleep', '60'], pass_fds=(lock.fd,), stdout=subprocess.DEVNULL, "
              "stderr=subprocess.DEVNULL); print(child.pid, flush=True)")
    parent = subprocess.run([sys.executable, "-c", script, str(tmp_path / "run")], capture_output=True, text=True,
                            timeout=60, check=True)
    child = int(parent.stdout.split()[0])
    try:
        with pytest.raises(RunDirectoryInUse) as refused:
            RunLock.acquire(tmp_path / "run")
        message = str(refused.value)
        assert f"in use by pid {child} (sleep 60), which still holds its lock" in message, message
        assert "has ended; wait for it to exit, or end it" in message, message
    finally:
        os.kill(child, signal.SIGKILL)
