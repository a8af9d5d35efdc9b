"""Your own environment (env.factory): loading and its errors, the vectorising adapter (padding, masks, bounds,
episodes of any length, termination), whole-episode chunks with fold-keeping ids, and CI-sized training of mpe2's
simple_spread, simple_speaker_listener and simple_tag, MaMuJoCo's 2-agent HalfCheetah (a physics environment) and
the from-scratch example on the inline runner (the service's roles in one process: services.launch.train_in_process)."""

import numpy as np
import pytest

from cmcl.config import ConfigError, load_config
from cmcl.envs.factory import EnvFactoryError
from cmcl.learners.maddpg import MADDPG
from cmcl.rollout.episodes import EpisodeChunker, WorldEpisodes
from cmcl.rollout.policy import NumpyPolicy
from cmcl.system import agent_layout, make_batched_env
from tests.in_process import train_tiny

REACH = "cmcl.envs.examples.reach:parallel_env"
EARLY_EXIT = "tests.early_exit:parallel_env"  # agent_0 terminates after 2 steps, agent_1 truncates after 5
MPE = {"spread": "mpe2.simple_spread_v3:parallel_env", "tag": "mpe2.simple_tag_v3:parallel_env",
       "speaker_listener": "mpe2.simple_speaker_listener_v4:parallel_env"}
CONTINUOUS = "env.factory_kwargs={continuous_actions=true, max_cycles=25}"
HALFCHEETAH = ["env.factory=gymnasium_robotics:mamujoco_v1.parallel_env",  # two agents of 3 joints each, Box(-1, 1)
               'env.factory_kwargs={scenario="HalfCheetah", agent_conf="2x3", max_episode_steps=25}']
TINY = ["env.num_envs=4", "maddpg.batch_size=16", "maddpg.warmup=96", "maddpg.hidden=32", "replay.capacity=600",
        "teachers.batch_size=16", "teachers.hidden=32", "teachers.num_folds=3", "icm.batch_size=16"]


class GreedyWalker:
    """The example's obvious policy: every agent steps at full speed toward its goal (obs = position, goal)."""

    @staticmethod
    def act(obs, *args, **kwargs):
        return np.clip((obs[..., 1:2] - obs[..., 0:1]) / 0.2, -1, 1).astype(np.float32)


def config(factory, *overrides):
    return load_config(None, [f"env.factory={factory}", *TINY, *overrides])


def test_a_malformed_or_missing_factory_is_refused_naming_it():
    with pytest.raises(ConfigError, match="env.factory.*package.module:callable.*'mpe2.simple_spread_v3'"):
        load_config(None, ["env.factory=mpe2.simple_spread_v3"])
    with pytest.raises(EnvFactoryError, match="cannot import module 'no_such_module'"):
        make_batched_env(config("no_such_module:env"), num_envs=1)
    with pytest.raises(EnvFactoryError, match="has no attribute 'nope'"):
        make_batched_env(config("mpe2.simple_spread_v3:nope"), num_envs=1)
    with pytest.raises(ConfigError, match="maddpg.discrete"):
        config(REACH, "maddpg.discrete=true")


def test_an_unsupported_space_is_named_with_its_agent():
    with pytest.raises(EnvFactoryError, match="agent 'agent_0' has action space MultiDiscrete.*only Box and Discrete"):
        make_batched_env(config(EARLY_EXIT, "env.factory_kwargs={space='multidiscrete'}"), num_envs=1)
    with pytest.raises(EnvFactoryError, match="agent 'agent_1' has action space Discrete\\(3, start=-1\\) but agent "
                                              "'agent_0' has Box.*Box and Discrete .* not supported"):
        make_batched_env(config(EARLY_EXIT, "env.factory_kwargs={space='mixed'}"), num_envs=1)


def test_teams_come_from_the_agent_id_prefix_and_must_match_the_config():
    cfg = config(MPE["tag"], CONTINUOUS)  # no [teams.*]: one team "agent", but tag has adversaries too
    env = make_batched_env(cfg, num_envs=1)
    assert env.teams == {"adversary": [0, 1, 2], "agent": [3]}
    with pytest.raises(ConfigError, match="adversary_0.*teams.<name>"):
        agent_layout(cfg, env)
    mapped = config(MPE["tag"], CONTINUOUS, 'env.team_of={"agent_0" = "prey"}', "teams.adversary.algorithm=cmcl",
                    "teams.prey.algorithm=maddpg")
    layout = agent_layout(mapped, make_batched_env(mapped, num_envs=1))
    assert layout.teams == {"adversary": [0, 1, 2], "prey": [3]} and layout.algorithms == ("cmcl",) * 3 + ("maddpg",)


def test_agents_that_differ_are_padded_and_their_missing_actions_masked():
    cfg = config(MPE["speaker_listener"], CONTINUOUS, "teams.speaker.algorithm=cmcl", "teams.listener.algorithm=per")
    env = make_batched_env(cfg, num_envs=3, seed=0)
    assert (env.obs_dims, env.act_dims, env.obs_dim, env.act_dim) == ((3, 11), (3, 5), 11, 5)
    obs = env.reset()
    assert obs.shape == (3, 2, 11) and not obs[:, 0, 3:].any() and obs[:, 1].any()
    layout = agent_layout(cfg, env)
    np.testing.assert_array_equal(layout.act_mask, [[1, 1, 1, 0, 0], [1, 1, 1, 1, 1]])
    maddpg = MADDPG(2, 11, 5, seed=0, act_mask=layout.act_mask)
    acted = maddpg.act(obs, 0.5, rng=np.random.default_rng(0))
    assert not acted[:, 0, 3:].any() and acted[:, 0, :3].any()
    policy = NumpyPolicy({k: v.detach().numpy() for k, v in maddpg.actor.state_dict().items()}, layout.act_mask)
    np.testing.assert_allclose(policy.act(obs, 0.0), maddpg.act(obs, 0.0), atol=1e-6)
    own = torch_policy_actions(maddpg, obs)
    assert not own[:, 0, 3:].any(), "the actor update's actions are masked too (the critic sees zeros there)"


def torch_policy_actions(maddpg, obs):
    import torch

    actions, _ = maddpg._policy(maddpg.actor, torch.as_tensor(obs).transpose(0, 1), sample=False)
    return actions.transpose(0, 1).detach().numpy()


def test_actions_map_onto_each_box_and_episodes_end_on_their_own_with_termination_flagged():
    env = make_batched_env(config(REACH), num_envs=2, seed=0)
    assert [float(env._env_action(0, np.array([a], np.float32))[0]) for a in (-1.0, 0.0, 1.0, 3.0)] == \
        pytest.approx([-0.2, 0.0, 0.2, 0.2])
    mpe = make_batched_env(config(MPE["speaker_listener"], CONTINUOUS), num_envs=1)
    np.testing.assert_allclose(mpe._env_action(0, np.array([-1.0, 0.0, 1.0, 0.7, 0.7], np.float32)), [0, 0.5, 1])
    obs = env.reset()
    ended_at, terminated = {}, {}
    for t in range(1, 40):
        toward = np.clip((obs[:, :, 1] - obs[:, :, 0]) / 0.2, -1, 1)[..., None].astype(np.float32)
        obs, _, ended, info = env.step(toward)
        for m, world in enumerate(np.flatnonzero(ended)):
            if int(world) not in ended_at:  # its first episode
                ended_at[int(world)], terminated[int(world)] = t, bool(info["terminated"][world].all())
                assert info["episode"]["length"][m] == t
    assert set(ended_at) == {0, 1} and all(terminated.values()), "a greedy walker reaches its goal before the limit"
    assert max(ended_at.values()) < 25 and len(set(ended_at.values())) == 2, "each world ends on its own"


def test_a_time_limit_or_env_truncation_is_not_a_termination():
    env = make_batched_env(config(REACH, "env.episode_length=3"), num_envs=2, seed=1)
    obs = env.reset()
    for _ in range(3):  # walk away from the goals: no world reaches them
        obs, _, ended, info = env.step(-np.sign(obs[:, :, 1:2] - obs[:, :, 0:1]).astype(np.float32))
    assert ended.all() and not info["terminated"].any()
    assert info["episode"]["length"].tolist() == [3, 3] and info["episode"]["return"].shape == (2, 2)


def test_whole_episode_chunks_keep_one_id_per_episode_whatever_the_lengths():
    chunker, rng = EpisodeChunker(3), np.random.default_rng(0)
    lengths = {0: [2, 5, 1], 1: [4, 4], 2: [8]}  # world -> its episode lengths (8 steps in all)
    left = {w: list(v) for w, v in lengths.items()}
    played = {w: 0 for w in lengths}
    for step in range(8):
        ended = np.zeros(3, bool)
        for w in range(3):
            if left[w]:
                played[w] += 1
                if played[w] == left[w][0]:
                    ended[w], played[w] = True, 0
                    left[w].pop(0)
        tag = np.full((3, 2, 1), step, np.float32)
        chunker.add(tag, rng.random((3, 2, 1), dtype=np.float32), np.zeros((3, 2), np.float32), tag,
                    np.zeros(3), ended)
    assert chunker.ready == 6
    first = chunker.pop(3, 0, "x", 0, 0)  # episodes 0, 1, 2: the first of every world (lengths 2, 4, 8)
    assert first.worlds == 3 and np.bincount(first.env_index).tolist() == [2, 4, 8]
    second = chunker.pop(3, 0, "x", 1, 0)  # then 3, 4, 5: world 0's 5-step and 1-step episodes, world 1's second
    assert np.bincount(second.env_index).tolist() == [5, 4, 1] and chunker.ready == 0 and not chunker.steps
    for chunk in (first, second):  # rows of one episode are consecutive steps, in step order
        for e in range(chunk.worlds):
            steps = chunk.obs[chunk.env_index == e, 0, 0]
            assert (np.diff(steps) == 1).all()


def test_lock_step_worlds_give_the_lock_step_chunk_and_ids():
    chunker, ids = EpisodeChunker(4), WorldEpisodes(4)
    for t in range(3):
        ended = np.full(4, t == 2)
        chunker.add(np.zeros((4, 1, 1), np.float32), np.zeros((4, 1, 1), np.float32), np.zeros((4, 1), np.float32),
                    np.zeros((4, 1, 1), np.float32), np.zeros(4), ended)
        ids.advance(ended)
    chunk = chunker.pop(4, 0, "x", 0, 0)
    np.testing.assert_array_equal(chunk.env_index, np.tile(np.arange(4), 3))
    np.testing.assert_array_equal(ids.ids, 4 + np.arange(4))


@pytest.mark.parametrize("name,teams", [("spread", []),
                                        ("speaker_listener", ["teams.speaker.algorithm=cmcl",
                                                              "teams.listener.algorithm=maddpg"]),
                                        ("tag", ["teams.adversary.algorithm=cmcl", "teams.agent.algorithm=per"])])
def test_mpe2_environments_train_on_the_inline_runner(name, teams, tmp_path):
    cfg = config(MPE[name], CONTINUOUS, "run.episodes=16", *teams)
    row, roles = train_tiny(cfg, tmp_path / "run")
    assert row["episodes"] >= 16 and row["env_steps"] == 16 * 25 and row["updates"] > 0
    assert set(row["window"]["reward"]) == set(roles.learner.layout.teams)
    assert np.isfinite(list(row["window"]["reward"].values())).all()


def test_a_physics_environment_outside_mpe_trains_on_the_inline_runner(tmp_path):
    cfg = load_config(None, [*HALFCHEETAH, *TINY, "env.episode_length=25", "run.episodes=8"])
    row, roles = train_tiny(cfg, tmp_path / "run")
    worker = roles.rollout[0]
    assert (worker.env.obs_dims, worker.env.act_dims, worker.layout.teams) == ((12, 12), (3, 3), {"agent": [0, 1]})
    assert roles.learner.layout.teams == {"agent": [0, 1]}
    assert row["episodes"] >= 8 and row["env_steps"] == 8 * 25 and row["updates"] > 0
    assert np.isfinite(row["window"]["reward"]["agent"])


def test_the_example_reports_success_and_its_terminations_reach_the_critic_target(tmp_path, monkeypatch):
    from services.roles.rollout import RolloutWorker

    monkeypatch.setattr(RolloutWorker, "_numpy_policy", lambda self, actor: GreedyWalker())  # every policy published
    cfg = config(REACH, "env.success_key=reached", "run.episodes=24")
    row, roles = train_tiny(cfg, tmp_path / "reach")
    assert row["window"]["success"] == 1.0
    replay = roles.replay.replay
    stored, size = replay.storage, replay.size
    assert (stored.done[:size].sum(0) == row["episodes"]).all(), "one terminal row per episode"
    counted = {k: roles.replay.counters[k] for k in ("inserts", "episodes", "updates")}
    rows, episodes = stored.id[:size].max(), stored.episode[:size].max()
    again, resumed = train_tiny(cfg, tmp_path / "reach", resume=True)  # its budget done: restored, nothing more
    assert {k: resumed.replay.counters[k] for k in counted} == counted and again["episodes"] == 24
    more, resumed = train_tiny(cfg, tmp_path / "reach", episodes=32, resume=True)
    assert more["episodes"] == 32 and more["window"]["success"] == 1.0
    stored = resumed.replay.replay.storage
    new = stored.id[: resumed.replay.replay.size] > rows
    assert new.any() and (stored.episode[: resumed.replay.replay.size][new] > episodes).all(), \
        "a resumed factory run starts new episodes"


def test_evaluation_and_the_gif_work_for_a_factory_environment(tmp_path):
    from cmcl.run.evaluate import evaluate_policy, render_gif
    from services.roles.learner import Learner

    cfg = config(REACH, "env.success_key=reached")
    maddpg = Learner(cfg, 0).maddpg  # the learner's untrained networks
    result = evaluate_policy(cfg, GreedyWalker(), episodes=20)
    assert result["success"] == 1.0 and result["episodes"] == 20, result
    random = evaluate_policy(cfg, None, episodes=20)
    assert random["success"] < 1.0 and random["reward"]["agent"] < result["reward"]["agent"]
    gif = render_gif(cfg, maddpg, tmp_path / "reach.gif")
    assert gif.stat().st_size > 0


def test_the_rollout_worker_sends_whole_episodes_of_any_length_and_the_replay_keeps_their_folds():
    from services.roles.replay_server import ReplayServer
    from services.roles.rollout import RolloutWorker

    cfg = config(REACH, "env.success_key=reached", "env.episode_length=12").to_dict()
    worker, server = RolloutWorker(cfg, 0, 0), ReplayServer(cfg)
    worker.policy = GreedyWalker()  # reaches the goals: episodes of different lengths, ended by termination
    lengths, sent = [], 0
    for seq in range(4):
        chunk, report = worker.rollout(None)
        assert chunk.seq == seq and chunk.worlds == 4 and set(chunk.env_index.tolist()) == set(range(4))
        for e in range(4):
            rows = np.flatnonzero(chunk.env_index == e)
            lengths.append(len(rows))
            assert chunk.done[rows[:-1]].sum() == 0, "only an episode's last row can be terminal"
        assert server.insert(chunk).accepted == chunk.rows
        sent += chunk.rows
        assert report.rollout.env_steps >= sent and (report.rollout.finished.success == 1.0).all()
    assert len(set(lengths)) > 1 and max(lengths) <= 12, lengths
    assert (server.replay.storage.done[:sent].sum(0) == 16).all(), "each episode ended by termination, last row"
    storage = server.replay.storage
    episode, fold = storage.episode[:sent], storage.fold[:sent]
    for e in np.unique(episode):
        assert len(set(fold[episode == e].tolist())) == 1, "one fold per episode"
    assert np.unique(episode).size == 16


@pytest.mark.slow
@pytest.mark.parametrize("name", ["spread", "speaker_listener", "tag", "halfcheetah"])
def test_each_environment_of_the_own_envs_grid_learns_above_the_random_policy(name, tmp_path):
    """The full run of the own_envs grid (experiments/own_envs.py), seed 0, inline: every team's held-out return
    (against random other teams when the teams compete) beats the random policy's by more than 5 on the same
    200 held-out episodes. A few minutes each on one free core (simple_tag, 6,000 episodes: about 10)."""
    from cmcl.run.evaluate import evaluate_policy
    from experiments.own_envs import OWN_ENVS

    env = OWN_ENVS[name]
    cfg = load_config(None, [f"env.factory={env.factory}", *env.sets, f"run.episodes={env.budget}", "run.seed=0"])
    _, roles = train_tiny(cfg, tmp_path / "run")
    random = evaluate_policy(cfg, None, episodes=200, seed=0)["reward"]
    for team in random:  # competing teams against random opponents, cooperating ones together
        others = tuple(t for t in random if t != team) if env.competing else ()
        trained = evaluate_policy(cfg, roles.learner.maddpg, episodes=200, seed=0,
                                  random_teams=others)["reward"][team]
        assert trained > random[team] + 5.0, (team, trained, random[team])
