"""Learning regression: the default settings must solve sparse navigation. A change that breaks learning (rewards,
schedules, priorities, networks) turns this red.

The default-suite test trains MADDPG with the inline runner (the service's roles in one process,
services.launch.train_in_process) on a small world (N=2, 3,000 episodes, fixed seed; about 15-25 s on one
core) and evaluates without exploration noise on 200 held-out worlds. The bar is "learned": a held-out coverage of
at least 0.4 and 5x the random policy's (0.055), not "solved". Why: a run either solves the task or stalls with
one landmark of two covered (coverage ~0.5), and which one a seed does depends on floating-point details of the
machine: seed 0 gave 0.98 on the machine that set the first bar (0.5) and 0.492 on another (2026-12-03), which
failed that bar. Measured there at 3,000 episodes, seeds 0/1/2/3: 0.492/0.990/0.993/0.540 (4,000 episodes:
0.495/1.0/1.0/0.777). A broken learner stays near the random policy's 0.055, far below both outcomes. How often
runs stall is a learning-quality question (the stall analysis, lab.report.stalls), not this regression test's.
The slow tests (`pytest -m slow`) run every algorithm for the full default budget (20,000 episodes, N=4) and
require held-out coverage >= 0.9 and success >= 0.8.
"""

from pathlib import Path

import pytest

from cmcl.config import load_config
from cmcl.run.evaluate import evaluate_policy
from cmcl.run.rundir import RunDirectory
from services.launch import train_in_process

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def train_and_evaluate(config_file: str, sets: list[str], run: Path) -> tuple[dict, dict]:
    """Train in one process in the run directory `run`; return the held-out evaluation of the policy and of a random
    one."""
    config = load_config(CONFIGS / config_file, [*sets, f"run.dir={run}"])
    _, roles = train_in_process(config, RunDirectory.create(run, config))
    return evaluate_policy(config, roles.learner.maddpg, 200, seed=1), evaluate_policy(config, None, 200, seed=1)


def test_maddpg_learns_small_sparse_navigation(tmp_path):
    trained, random = train_and_evaluate("spread_maddpg.toml",
                                         ["env.num_agents=2", "run.episodes=3000", "run.seed=0"], tmp_path / "run")
    assert random["coverage"] < 0.1
    assert trained["coverage"] >= 0.4, f"held-out coverage {trained['coverage']:.3f} (random {random['coverage']:.3f})"
    assert trained["coverage"] >= 5 * random["coverage"]


@pytest.mark.slow
@pytest.mark.timeout(3600)  # 20,000 episodes: 3-10 min on one core, more on a shared machine
@pytest.mark.parametrize("algorithm", ["maddpg", "per", "acl", "cmcl"])
def test_every_algorithm_solves_sparse_navigation_at_the_full_budget(algorithm, tmp_path):
    trained, random = train_and_evaluate(f"spread_{algorithm}.toml", [], tmp_path / "run")  # all 20,000 episodes
    assert trained["coverage"] >= 0.9 and trained["success"] >= 0.8, (trained, random)
