"""Curiosity as an intrinsic reward with a decaying weight (icm.intrinsic_reward_decay, ICMConfig.intrinsic_coef):
the schedule's values, and the reward the learner role trains on at update t is the row's reward plus coef(t)·ρ
(ρ the ICM scorer stored), on a tiny inline run of uniform MADDPG with curiosity as its reward (the service runs the
same Learner role: services.runtime.calls)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmcl.config import ConfigError, ICMConfig, config_from_dict
from cmcl.run.rundir import RunDirectory
from services.launch import train_in_process


def test_the_weight_decays_linearly_or_exponentially_over_learner_updates():
    linear = ICMConfig(intrinsic_reward_coef=0.4, intrinsic_reward_decay="linear", intrinsic_reward_decay_updates=100)
    assert [linear.intrinsic_coef(t) for t in (0, 25, 100, 500)] == pytest.approx([0.4, 0.3, 0.0, 0.0])
    expo = ICMConfig(intrinsic_reward_coef=0.4, intrinsic_reward_decay="exponential",
                     intrinsic_reward_decay_updates=100)
    assert expo.intrinsic_coef(100) == pytest.approx(0.4 / math.e)
    assert ICMConfig(intrinsic_reward_coef=0.4).intrinsic_coef(10**6) == 0.4
    with pytest.raises(ConfigError, match=r"^icm.intrinsic_reward_decay_updates must be >= 1, got 0$"):
        ICMConfig(intrinsic_reward_decay_updates=0)


class RecordingMADDPG:
    """The learner's real MADDPG, recording the minibatch each update is given (named so; everything else is the
    MADDPG's own)."""

    def __init__(self, inner):
        self.inner, self.minibatch = inner, None

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def update(self, minibatch):
        self.minibatch = minibatch
        return self.inner.update(minibatch)


@pytest.mark.parametrize("decay,at,weight", [("linear", 300, 0.5), ("exponential", 600, math.exp(-1.0))])
def test_the_learner_trains_on_reward_plus_the_decayed_weight_times_rho(tiny_config, tmp_path, decay, at, weight):
    data = tiny_config("maddpg", service=True, dir=str(tmp_path / "run")).to_dict()
    data["icm"].update(intrinsic_reward_coef=2.0, intrinsic_reward_decay=decay, intrinsic_reward_decay_updates=600)
    config = config_from_dict(data)
    summary, roles = train_in_process(config, RunDirectory.create(config.run.dir, config))
    assert roles.icm is not None and summary["updates"] > 0
    progress = [r for r in RunDirectory.open(config.run.dir).rows("progress") if "intrinsic_reward" in r]
    assert progress and all(r["intrinsic_reward"] > 0 for r in progress)  # the run's rows show coef(t)·ρ
    batch, _ = roles.replay.sample(1)
    assert batch is not None and np.any(batch.rows["curiosity"] > 0)
    learner = roles.learner
    learner.maddpg.updates = at
    learner.maddpg = recorder = RecordingMADDPG(learner.maddpg)
    _, report = learner.update(batch)
    a = learner.layout.icm_agents
    assert a.tolist() == list(range(config.env.spread.num_agents))  # uniform sampling: every agent's ICM
    added = 2.0 * weight * batch.rows["curiosity"][0][a, :, a]
    np.testing.assert_allclose(recorder.minibatch["rew"][a, :, a], batch.rows["rew"][0][a, :, a] + added, rtol=1e-5)
    assert report.learner.intrinsic_reward == pytest.approx(float(added.mean()), rel=1e-5)  # what the metrics show


@pytest.mark.parametrize("frozen", [False, True])
def test_a_frozen_icm_scores_with_its_random_networks_and_never_fits(frozen):
    """icm.frozen, the intrinsic reward's control: the same ICM role scores ρ, its networks stay at their
    initialisation (an unfrozen one's change with its first fit step)."""
    import torch

    from services.roles.icm import ICMWorker
    from services.roles.replay_server import ReplayServer
    from services.roles.rollout import RolloutWorker
    from tests.in_process import in_process_config

    cfg = in_process_config("maddpg", icm={"intrinsic_reward_coef": 1.0, "frozen": frozen})
    replay, worker, icm = ReplayServer(cfg), RolloutWorker(cfg, 0, 0), ICMWorker(cfg, 0)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    before = [p.detach().clone() for p in icm.icm.parameters()]
    work, _ = replay.work(icm.scorer, 2)
    scores, _ = icm.score(work)
    assert scores.values.shape[1] == 4 and np.isfinite(scores.values).all() and (scores.values > 0).all()
    same = all(torch.equal(b, p) for b, p in zip(before, icm.icm.parameters(), strict=True))
    assert same == frozen


def test_a_summary_keeps_curiositys_reward_over_the_first_tenth_of_updates_and_the_whole_run():
    from experiments.measures import intrinsic_over_training

    rows = [{"episodes": 10 * i, "updates": 100 * i, "intrinsic_reward": 1.0 / i} for i in range(1, 21)]
    rows.insert(0, {"episodes": 0, "updates": 0})  # before the first update: no intrinsic_reward in the row
    out = intrinsic_over_training(rows)
    assert out["intrinsic_reward_first_tenth"] == pytest.approx((1.0 + 0.5) / 2, abs=1e-6)  # updates <= 200 of 2000
    assert out["intrinsic_reward_mean"] == pytest.approx(np.mean([1.0 / i for i in range(1, 21)]), abs=1e-6)
    assert out["intrinsic_curve"]["updates"] == [100 * i for i in range(1, 21)]
    assert out["intrinsic_curve"]["intrinsic_reward"][:2] == [1.0, 0.5]
    early = intrinsic_over_training(rows, upto=10)
    assert early["intrinsic_reward_first_tenth"] == early["intrinsic_reward_mean"] == 1.0
    assert intrinsic_over_training([{"episodes": 5, "updates": 3}]) == {}
