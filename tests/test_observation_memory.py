"""Observations a new user's environment brings (subprocesses of `python -m cmcl train`): a replay too large for this
machine (cooperative_pong_v6's 280×480×3 images) is refused in one line naming replay.capacity and the size, before
anything is allocated, and observations of rank > 1 (pursuit_v5's 7×7×3 grids) are flattened for the MLP networks,
said in one line (cmcl.run.preflight)."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import pytest

from cmcl.replay.storage import TransitionStorage
from cmcl.run.preflight import available_memory, storage_bytes_per_row

ROOT = Path(__file__).resolve().parents[1]


ADDRESS_SPACE = 12 * 2**30  # bytes: a machine where numpy cannot map a probe buffer of tens of GiB lazily


def limit_address_space() -> None:
    """In the child before it runs: at most ADDRESS_SPACE bytes of virtual memory (RLIMIT_AS), as on a machine
    without overcommit, so that an allocation of the replay's size fails at once instead of being mapped lazily."""
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))


def train(*overrides: str, limited: bool = False) -> subprocess.CompletedProcess:
    sets = [arg for text in overrides for arg in ("--set", text)]
    return subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", *sets, "--no-eval"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300,
                          preexec_fn=limit_address_space if limited else None)


def test_the_computed_row_is_what_the_storage_allocates():
    class Layout:
        num_agents, obs_dim, act_dim = 3, 17, 5

    storage = TransitionStorage(capacity=10, n_agents=3, obs_dim=17, act_dim=5)
    arrays = [value for value in vars(storage).values() if hasattr(value, "nbytes")]
    arrays += [*storage.scores.values(), *storage.scored.values()]
    assert storage_bytes_per_row(Layout) * 10 == sum(a.nbytes for a in arrays)


def test_image_observations_too_large_for_the_replay_are_refused_in_one_line(tmp_path):
    pytest.importorskip("pettingzoo.butterfly.cooperative_pong_v6", reason="PettingZoo's butterfly envs (pygame, "
                        "pymunk) are not installed")
    if available_memory() is None:
        pytest.skip("this machine's available memory cannot be read (not Linux)")
    done = train("env.factory=pettingzoo.butterfly.cooperative_pong_v6:parallel_env", f"run.dir={tmp_path / 'run'}",
                 limited=True)  # the default replay.capacity
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and len(errors) == 1
    assert errors[0].startswith("error: replay.capacity = 5000 needs about ") and "2 agents × 403,200-wide" in errors[0]
    assert "more than the " in errors[0] and not (tmp_path / "run").exists()


def test_grid_observations_are_flattened_said_in_one_line(tmp_path):
    pytest.importorskip("pettingzoo.sisl", reason="PettingZoo's SISL envs (pettingzoo[sisl]) are not installed")
    done = train("env.factory=pettingzoo.sisl.pursuit_v5:parallel_env", "env.factory_kwargs={max_cycles=6}",
                 "env.num_envs=2", "maddpg.warmup=16", "maddpg.batch_size=8", "replay.capacity=200",
                 "run.episodes=2", f"run.dir={tmp_path / 'run'}")
    assert done.returncode == 0, done.stderr
    out = done.stdout + done.stderr
    assert ("note: the observations of agent 'pursuer_0' (and 7 more agents alike) have shape (7, 7, 3): they are "
            "flattened to 147 inputs of the MLP networks") in out
