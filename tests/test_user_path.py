"""The README's commands run as a user runs them: subprocesses, real signals, a real embedded Ray, a tiny budget.

- `make run` ends with the held-out evaluation line and writes the GIF; `python -m cmcl.run.evaluate RUN_DIR` then
  finds the service's policy by itself, as it does an inline run's.
- The service runs through the one entry point (`python -m cmcl train --runner service`, `python -m cmcl resume`),
  and through its own command (`python -m services.launch`), which is an alias with the same flags.
- Ctrl-C (SIGINT to the whole process group, as a terminal sends it) and SIGTERM mid-run: exit 130 / 143 (`make run`:
  make's own "Interrupt", not "Error 130"), no traceback, every role's checkpoint on disk, a one-line resume hint, which
  run as printed goes on from the policy it had.
- SIGKILL of the launcher: no process of the Ray it started is left; `--resume` goes on from the last checkpoint.
- A second launcher on a run directory in use is refused, naming the holder, and the first run is unharmed.

"Goes on from the policy" is checked where it is decided: the first episodes of the resumed run are played with
the checkpoint's weight version (a learner that started afresh publishes version 0).
"""

from __future__ import annotations

import json
import os
import queue
import shlex
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from cmcl.run.rundir import RunDirectory
from services.runtime.reaper import descendants, process_table
from tests.evaluation_output import evaluation_json

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
LINE_TIMEOUT_S = 180  # for any one line of output (Ray's start on a loaded 2-core machine takes up to ~30 s)

pytestmark = pytest.mark.timeout(600)


def default_sigint() -> None:
    """In the child before it runs: SIGINT's default action, as a terminal's job has it. A suite started in the
    background of a non-interactive shell inherits SIGINT ignored, and make keeps an ignored SIGINT ignored."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Launched:
    """A command started in its own process group (as a shell starts a job), its output read line by line, and the
    processes below it recorded (pid, start time) while it runs."""

    def __init__(self, args: list[str], cwd: Path = ROOT):
        self.proc = subprocess.Popen(args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     start_new_session=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
                                     preexec_fn=default_sigint)
        self.lines: list[str] = []
        self.seen: dict[int, int] = {}
        self._queue: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        for line in self.proc.stdout:
            self._queue.put(line)
        self._queue.put(None)

    def _record(self) -> None:
        self.seen.update(descendants({self.proc.pid}, process_table()))

    def wait_for(self, predicate, what: str) -> str:
        """Read lines until one satisfies `predicate`; fail naming `what` if the output ends first."""
        while True:
            self._record()
            try:
                line = self._queue.get(timeout=LINE_TIMEOUT_S)
            except queue.Empty:
                raise AssertionError(f"no line for {LINE_TIMEOUT_S} s while waiting for {what}:\n{self.text}") from None
            if line is None:
                raise AssertionError(f"output ended while waiting for {what}:\n{self.text}")
            self.lines.append(line)
            if predicate(line):
                return line

    def progress_lines(self, count: int, min_updates: int = 1) -> None:
        """Wait for `count` progress lines reporting at least `min_updates` learner updates."""
        seen = 0

        def counts(line: str) -> bool:
            nonlocal seen
            if line.startswith("ep ") and int(line.split("| upd ")[1].split()[0]) >= min_updates:
                seen += 1
            return seen >= count

        self.wait_for(counts, f"{count} progress lines with >= {min_updates} updates")

    def finish(self, timeout: float = 300) -> int:
        """Wait for the exit; all output read."""
        self.proc.wait(timeout=timeout)
        while (line := self._queue.get(timeout=LINE_TIMEOUT_S)) is not None:
            self.lines.append(line)
        return self.proc.returncode

    @property
    def text(self) -> str:
        return "".join(self.lines)


def alive(recorded: dict[int, int]) -> set[int]:
    """The recorded processes still running (same pid and start time)."""
    table = process_table()
    return {pid for pid, start in recorded.items() if table.get(pid, (0, -1))[1] == start}


def wait_until_gone(recorded: dict[int, int], timeout: float = 60) -> set[int]:
    """Poll until none of `recorded` runs (the reaper works on its own clock); returns what is left at the end."""
    deadline = time.monotonic() + timeout
    while (left := alive(recorded)) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left


def launch(run_dir: Path, *extra: str) -> Launched:
    """A service run through the one entry point."""
    return Launched([PY, "-m", "cmcl", "train", "--runner", "service", "--config", "configs/spread_cmcl.toml",
                     "--set", f"run.dir={run_dir}", "--metrics-port", "0", "--set", "run.max_seconds=120", *extra])


# The two ways to resume a service run: the one entry point, which finds the runner from the run directory, and
# the service's own command (the cluster command of the deploy files).
RESUME_COMMANDS = {"cmcl": [PY, "-m", "cmcl", "resume"], "services.launch": [PY, "-m", "services.launch", "--resume"]}


def resume(run_dir: Path, command: str | list[str]) -> Launched:
    """`command`: a key of RESUME_COMMANDS, or the argv of a printed resume hint (which names the run itself)."""
    argv = [*RESUME_COMMANDS[command], str(run_dir)] if isinstance(command, str) else command
    return Launched([*argv, "--metrics-port", "0"])


def learner_version(run_dir: Path) -> int:
    """The policy version of the run's newest verified learner checkpoint."""
    policy = RunDirectory.open(run_dir).newest_policy()
    assert policy is not None and policy.path.parent.name == "service", f"no service policy in {run_dir}"
    return int(policy.state["version"])


def first_versions_after(run_dir: Path, episode: int, count: int = 20) -> list[int]:
    """Weight versions of the first `count` episodes logged after `episode`."""
    rows = [r for r in RunDirectory.open(run_dir).rows("episode") if r["episodes"] > episode]
    assert rows, f"no episode logged after {episode}"
    return [int(r["weight_version"]) for r in rows[:count]]


def resume_hint(text: str) -> list[str]:
    """The resume command a stopped run printed ("... Resume with: COMMAND"), as the argv a shell would run."""
    hints = [line.split("Resume with: ", 1)[1] for line in text.splitlines() if "Resume with: " in line]
    assert len(hints) == 1, f"expected one resume hint:\n{text}"
    return shlex.split(hints[0])


def assert_clean_stop(run: Launched, code: int, name: str, run_dir: Path) -> None:
    assert run.finish() == code, run.text
    assert "Traceback" not in run.text and "SIGTERM received at time" not in run.text, run.text
    assert f"stopped by {name}" in run.text and resume_hint(run.text)[-3:] == ["cmcl", "resume", str(run_dir)]
    service = run_dir / "checkpoints" / "service"
    for role in ("learner", "icm", "teacher_0-1-2-3-4"):
        assert (service / f"{role}.pt.manifest.json").is_file(), f"no {role} checkpoint: {sorted(service.iterdir())}"
    assert json.loads((run_dir / "summary.json").read_text())["ended"] == name


def resume_then_stop(run_dir: Path, version: int, logged: int, stop: signal.Signals,
                     command: str | list[str]) -> None:
    """Resume with `command` (a key of RESUME_COMMANDS, or a printed hint's argv), which must announce the
    checkpoint's policy `version`; stop it with `stop` at the first progress line that counts a learner update of
    the resumed run; a clean stop, and the resumed run's first episodes (after episode `logged`) played with that
    policy."""
    checkpointed = json.loads((run_dir / "checkpoints" / "service" / "supervisor.json").read_text())
    again = resume(run_dir, command)
    again.wait_for(lambda line: f"(policy version {version})" in line, "the resume notice")
    again.progress_lines(1, min_updates=checkpointed["status"]["updates"] + 1)
    os.killpg(again.proc.pid, stop)
    assert_clean_stop(again, 128 + stop, stop.name, run_dir)
    assert wait_until_gone(again.seen) == set()
    assert min(first_versions_after(run_dir, logged)) >= version  # a fresh learner would publish version 0


def make_run(run_dir: Path, *flags: str) -> Launched:
    """`make run` into `run_dir` for 96 episodes (a budget in episodes, not seconds: under load a 10 s budget once
    ended before the first episode), finished with exit 0."""
    run = Launched(["make", "-s", "run", f"RUN_ARGS=--set run.dir={run_dir} --set run.episodes=96 "
                                         "--set run.max_seconds=600 --metrics-port 0 " + " ".join(flags)])
    assert run.finish() == 0, run.text
    return run


def make_resume(run_dir: Path, counted: str, *flags: str) -> Launched:
    """The README's `make resume` of `run_dir` for 32 more episodes (it says so), finished with exit 0. `counted`:
    the summary's count of episodes done ("episodes", or "episodes_logged": the episode rows logged)."""
    done = json.loads((run_dir / "summary.json").read_text())[counted]
    resumed = Launched(["make", "-s", "resume", f"RUN_DIR={run_dir}", "RESUME_EPISODES=32",
                        "RUN_ARGS=--no-eval " + " ".join(flags)])
    assert resumed.finish() == 0, resumed.text
    assert f"run.episodes: {done + 32} (32 more than the {done} done)" in resumed.text, resumed.text
    assert json.loads((run_dir / "summary.json").read_text())[counted] >= done + 32
    assert not alive(resumed.seen), f"processes left behind: {alive(resumed.seen)}"
    return resumed


def test_make_run_ends_with_the_held_out_evaluation_and_a_gif_and_evaluate_finds_the_policy(tmp_path):
    run_dir = tmp_path / "make-run"
    run = make_run(run_dir)
    assert "held-out evaluation (200 new worlds, no exploration noise): coverage" in run.text, run.text
    assert "return[agent]" in run.text and "worlds with an uncovered landmark at the final step" in run.text, run.text
    assert (run_dir / "trained.gif").stat().st_size > 0 and (run_dir / "learning_curve.png").is_file()
    assert not alive(run.seen), f"processes left behind: {alive(run.seen)}"
    evaluated = subprocess.run([PY, "-m", "cmcl", "evaluate", str(run_dir), "--episodes", "20", "--no-gif"], cwd=ROOT,
                               capture_output=True, text=True, timeout=300)
    assert evaluated.returncode == 0, evaluated.stderr
    result = evaluation_json(evaluated.stdout)
    assert Path(result["checkpoint"]).name.startswith("learner-") and result["episodes"] == 20


def test_make_resume_trains_a_finished_run_for_more_episodes(tmp_path, tiny_config_file):
    """The README's `make resume` (the Makefile's target, through make) on a finished tiny inline run: `cmcl
    resume` finds the runner that wrote the run. The same target on `make run`'s service run is the extended test
    below; the service's resume itself stays in the default run (tests/test_service_ray.py)."""
    config = tiny_config_file("maddpg", dir=str(tmp_path / "run"), episodes=4)
    trained = subprocess.run([PY, "-m", "cmcl", "train", "--runner", "inline", "--config", str(config), "--quiet",
                              "--no-eval"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert trained.returncode == 0, trained.stderr
    make_resume(tmp_path / "run", "episodes")


# out of the default run (its 10-minute budget): `make resume` of an inline run stays in the default run above
@pytest.mark.extended
def test_make_resume_of_make_runs_service_run_trains_it_further(tmp_path):
    """Through make, the README's CMCL variant of `make run` (RUN_ARGS="--set teams.agent.algorithm=cmcl"), then
    `make resume` of it."""
    run_dir = tmp_path / "make-run"
    make_run(run_dir, "--no-eval", "--set teams.agent.algorithm=cmcl")
    assert 'algorithm = "cmcl"' in (run_dir / "config.toml").read_text()
    make_resume(run_dir, "episodes_logged", "--metrics-port 0")


# out of the default run (its 10-minute budget): the inline Ctrl-C test and `make resume` in the make-run test stay in
# the default run
@pytest.mark.extended
def test_make_run_stopped_by_ctrl_c_a_second_launcher_refused_and_the_printed_command_resumes_the_policy(tmp_path):
    run_dir = tmp_path / "run"
    # the README's CMCL variant of make run: every role (learner, teachers, ICM) must checkpoint on Ctrl-C
    first = Launched(["make", "-s", "run", f"RUN_ARGS=--set run.dir={run_dir} --set run.max_seconds=120 "
                                           "--set teams.agent.algorithm=cmcl --metrics-port 0"])
    first.progress_lines(1, min_updates=16)
    second = subprocess.run([PY, "-m", "services.launch", "--config", "configs/spread_cmcl.toml", "--set",
                             f"run.dir={run_dir}", "--overwrite", "--metrics-port", "0"], cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert second.returncode == 2 and "is in use by pid " in second.stderr, second.stderr
    holder = int(second.stderr.split("is in use by pid ")[1].split()[0].rstrip(".,;:)"))
    assert holder in first.seen, f"the run is held by pid {holder}, not by the make run: {second.stderr}"
    os.killpg(first.proc.pid, signal.SIGINT)  # what a terminal does on Ctrl-C: the whole foreground group
    # make itself dies of the SIGINT after the run's graceful stop, saying "Interrupt"; the run's exit 130 is not
    # reported as an error of make's ("Error 130"). The refused second launcher did not harm the first run.
    assert_clean_stop(first, -signal.SIGINT, "SIGINT", run_dir)
    assert "Error" not in first.text and first.text.rstrip().endswith("Interrupt"), first.text
    assert wait_until_gone(first.seen) == set()
    version, episodes = learner_version(run_dir), json.loads((run_dir / "summary.json").read_text())["episodes_logged"]
    assert version > 0

    resume_then_stop(run_dir, version, episodes, signal.SIGTERM, resume_hint(first.text))  # typed as printed
    assert learner_version(run_dir) > version


# out of the default run (its 10-minute budget): the service's stop and resume stay in the default run by the inline
# Ctrl-C test and tests/test_service_ray.py
@pytest.mark.extended
def test_sigkill_of_the_launcher_leaves_no_ray_process_and_resume_goes_on_from_the_last_checkpoint(tmp_path):
    run_dir = tmp_path / "run"
    first = launch(run_dir, "--set", "service.checkpoint_every_s=2")
    first.progress_lines(1, min_updates=16)
    manifest = run_dir / "checkpoints" / "service" / "learner.pt.manifest.json"
    first.wait_for(lambda line: manifest.is_file() and learner_version(run_dir) > 0, "a learner checkpoint")
    first.proc.kill()  # the launcher alone, as the OOM killer or `kill -9 PID` would
    assert first.finish() == -signal.SIGKILL
    assert len(first.seen) >= 5  # gcs, raylet, agents, workers, the reaper
    assert wait_until_gone(first.seen) == set(), "processes of the killed launcher's Ray are still running"
    version = learner_version(run_dir)
    logged = json.loads((run_dir / "checkpoints" / "service" / "supervisor.json").read_text())["episodes_logged"]

    resume_then_stop(run_dir, version, logged, signal.SIGINT, "services.launch")


def test_inline_runner_stops_on_ctrl_c_refuses_a_second_writer_and_resumes(tmp_path):
    """`python -m cmcl train --runner inline` (the service's roles in one process, no Ray) stopped by Ctrl-C mid-run:
    exit 130, every role checkpointed (a checkpoint at the stop, before service.checkpoint_every_s), a resume hint;
    a second writer is refused naming the first; `resume` goes on from the policy it had."""
    run_dir = tmp_path / "inline"
    first = Launched([PY, "-m", "cmcl", "train", "--runner", "inline", "--config", "configs/spread_maddpg.toml",
                      "--set", f"run.dir={run_dir}", "--set", "run.episodes=100000"])
    first.progress_lines(2, min_updates=1)
    second = subprocess.run([PY, "-m", "cmcl", "resume", str(run_dir)], cwd=ROOT, capture_output=True, text=True,
                            timeout=120)
    assert second.returncode == 2 and f"is in use by pid {first.proc.pid}" in second.stderr, second.stderr
    os.killpg(first.proc.pid, signal.SIGINT)
    assert first.finish() == 130 and "Traceback" not in first.text, first.text
    assert resume_hint(first.text)[-3:] == ["cmcl", "resume", str(run_dir)]
    assert not (run_dir / "ray_shutdown.log").exists() and not alive(first.seen), "no Ray, nothing left running"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["ended"] == "SIGINT" and summary["runner"] == "inline"
    stopped_at, version = summary["episodes_logged"], learner_version(run_dir)
    assert version > 0 and (run_dir / "checkpoints" / "service" / "replay" / "manifest.json").is_file()

    again = subprocess.run([PY, "-m", "cmcl", "resume", str(run_dir), "--set", f"run.episodes={stopped_at + 40}",
                            "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and f"(policy version {version})" in again.stdout, again.stdout + again.stderr
    assert "metrics: http" not in again.stdout and not (run_dir / "ray_shutdown.log").exists()
    assert min(first_versions_after(run_dir, stopped_at)) >= version  # a fresh learner would publish version 0
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["runner"] == "inline" and summary["episodes_logged"] >= stopped_at + 40
    evaluated = subprocess.run([PY, "-m", "cmcl", "evaluate", str(run_dir), "--episodes", "20", "--no-gif"], cwd=ROOT,
                               capture_output=True, text=True, timeout=300)
    assert evaluated.returncode == 0, evaluated.stderr
    assert Path(evaluation_json(evaluated.stdout)["checkpoint"]) == RunDirectory.open(run_dir).newest_policy().path
