"""The online critic is a scorer the learner hosts (ACL td_self): every row the buffer holds gets its |δ| from the
learner's online critics, on the inline runner and on the service alike (both schedule the same roles:
services.runtime.calls), and no row is sampled before they have scored it (ALGORITHM.md A11: score at insertion)."""

import numpy as np
import pytest

from cmcl.config import config_from_dict
from cmcl.replay.messages import ONLINE_TD
from cmcl.run.rundir import RunDirectory
from services.launch import train_in_process
from tests.recording_calls import recorded_run


def td_self_config(tiny_config, tmp_path):
    """The tiny ACL config with the td_self variant (its difficulty: the online critics' |δ|), 24 episodes."""
    data = tiny_config("acl", service=True, dir=str(tmp_path / "run"), episodes=24).to_dict()
    data["teams"]["agent"]["acl_variant"] = "td_self"
    return config_from_dict(data)


def test_every_stored_row_is_scored_by_the_online_critics(tiny_config, tmp_path):
    config = td_self_config(tiny_config, tmp_path)
    summary, roles = train_in_process(config, RunDirectory.create(config.run.dir, config))
    replay, scoring = roles.replay.replay, roles.replay.scoring
    assert summary["updates"] > 0 and scoring.online_td
    valid, stamp = scoring.score_stamps(replay, online_td=True)
    assert valid.size == replay.size
    assert (stamp >= 0).all(), f"{int((stamp < 0).sum())} of {valid.size} rows never scored by the online critics"
    td = replay.storage.scores["td_abs"][valid]
    assert replay.storage.scored["td_abs"][valid].all() and np.isfinite(td).all() and (td > 0).any()


@pytest.mark.parametrize("in_process", [True, False], ids=["in_process", "ray_service"])
def test_no_row_of_a_td_self_run_is_sampled_before_the_online_critics_scored_it(in_process, tiny_config, tmp_path,
                                                                               request):
    """The sampled (slot, generation) pairs and the online critics' Scores, read from the messages of a real run
    in the replay server's order: every sampled row had its online |δ| before it was sampled."""
    if not in_process:
        request.getfixturevalue("ray_cluster")
    summary, outcome = recorded_run(td_self_config(tiny_config, tmp_path), tmp_path / "run", in_process)
    sampled = set(outcome.sampled())
    assert summary["updates"] > 0 and len(sampled) > 100 and ONLINE_TD in outcome.columns
    early = outcome.sampled_before_scored(ONLINE_TD)
    assert not early, f"{len(early)} of {len(sampled)} sampled rows were not scored yet, e.g. {sorted(early)[:3]}"


def test_curiosity_as_an_intrinsic_reward_reaches_the_learner_on_the_inline_runner(tiny_config, tmp_path):
    """icm.intrinsic_reward_coef > 0: the learner's minibatch rewards of each curiosity agent are its rows' reward
    plus coef × the ρ the ICM scorer stored for them (the same roles on the service: services.runtime.calls)."""
    from cmcl.learners.network_steps import learner_update

    config = config_from_dict({**tiny_config("cmcl", service=True, dir=str(tmp_path / "run")).to_dict(),
                               "icm": {**tiny_config("cmcl").to_dict()["icm"], "intrinsic_reward_coef": 2.0}})
    _, roles = train_in_process(config, RunDirectory.create(config.run.dir, config))
    server = roles.replay
    batch, _ = server.sample(1)
    assert batch is not None and np.any(batch.rows["curiosity"] > 0)
    a = roles.learner.layout.icm_agents
    recorder = RecordingMADDPG()
    learner_update(recorder, batch.minibatch(0, False), a, 2.0)
    expected = batch.rows["rew"][0][a, :, a] + 2.0 * batch.rows["curiosity"][0][a, :, a]
    np.testing.assert_allclose(recorder.minibatch["rew"][a, :, a], expected, rtol=1e-6)
    assert "curiosity" not in recorder.minibatch


class RecordingMADDPG:
    """A stand-in for MADDPG (named so): its update records the minibatch it is given."""

    def update(self, minibatch):
        self.minibatch = minibatch
        return {}


def test_an_intrinsic_reward_under_uniform_sampling_trains_an_icm_for_every_agent(tiny_config):
    """MADDPG's uniform sampling with icm.intrinsic_reward_coef > 0 (docs/SPARSE_TASKS.md): every agent is a
    curiosity agent, so the run has an ICM role to score ρ."""
    from cmcl.system import layout_of

    data = tiny_config("maddpg").to_dict()
    data["icm"]["intrinsic_reward_coef"] = 1.0
    config = config_from_dict(data)
    assert config.trains_icm and layout_of(config).icm_agents.tolist() == list(range(config.env.spread.num_agents))
