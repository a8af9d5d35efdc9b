"""The landmark-assignment signal (maddpg.assignment_loss, cmcl.learners.entity.assignment): the assignment on hand-made
geometries, its reading of the observation, the loss wired into the actor step (and absent when off), the refusals."""

import itertools

import numpy as np
import pytest
import torch

from cmcl.config import ConfigError, load_config
from cmcl.config.runners import check_runner_keys
from cmcl.envs.batched_spread import BatchedSparseSpread
from cmcl.envs.entities import spread_layout, tag_layout
from cmcl.envs.params import SpreadParams, TagParams
from cmcl.learners.entity import assignment
from cmcl.learners.entity.assignment import AssignmentTerm, assigned_landmark, assignment_targets
from cmcl.learners.maddpg import MADDPG

torch.set_num_threads(1)

# Greedy nearest-landmark would crowd: agents 0 and 1 are both nearest to landmark 0. The minimum total distance
# sends agent 2 to landmark 2 and agent 0 to landmark 1 (1.0 + 0.2 + 1.0 = 2.2 against 0.2 + 1.4 + 1.0 = 2.6).
AGENTS = np.array([[0.0, 0.0], [0.4, 0.0], [10.0, 0.0]])
LANDMARKS = np.array([[0.2, 0.0], [-1.0, 0.0], [10.0, 1.0]])


def test_the_optimal_assignment_separates_agents_that_greedy_nearest_would_crowd():
    nearest = np.linalg.norm(AGENTS[:, None] - LANDMARKS[None], axis=-1).argmin(1)
    assert nearest.tolist() == [0, 0, 2]  # greedy crowds landmark 0
    rows = np.stack([AGENTS, AGENTS[[1, 0, 2]], AGENTS[[2, 1, 0]], AGENTS - AGENTS[1]])  # each row's agent 0 asks
    lms = np.stack([LANDMARKS, LANDMARKS, LANDMARKS, LANDMARKS - AGENTS[1]])
    assert assigned_landmark(rows, lms).tolist() == [1, 0, 2, 1]  # row 3: row 0 moved


def test_absent_agents_and_landmarks_take_no_part():
    rows, lms = np.stack([AGENTS] * 4), np.stack([LANDMARKS] * 4)
    agent_present = np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1], [1, 1, 1]], bool)
    landmark_present = np.array([[1, 1, 0], [1, 0, 1], [1, 1, 1], [0, 1, 1]], bool)
    # row 0: agents 0, 1 on landmarks 0, 1 -> the same split as with three; row 1: agent 0 alone near landmark 0
    # (landmark 1 absent); row 2: agent 0 absent; row 3: landmark 0 absent -> agent 0 takes landmark 1
    assert assigned_landmark(rows, lms, agent_present, landmark_present).tolist() == [1, 0, -1, 1]
    more_agents = assigned_landmark(AGENTS[None], LANDMARKS[None], None, np.array([[1, 1, 0]], bool))
    assert more_agents.tolist() == [1]  # three agents, two landmarks: agent 0 still gets one here
    assert assigned_landmark(AGENTS[None, [2, 0, 1]], LANDMARKS[None], None, np.array([[1, 1, 0]], bool)
                             ).tolist() == [-1]  # the far agent is the one left without a landmark


def test_it_is_the_minimum_total_distance_over_every_permutation():
    rng = np.random.default_rng(1)
    n, r = 5, 40
    agents, lms = rng.uniform(-1, 1, (r, n, 2)), rng.uniform(-1, 1, (r, n, 2))
    cost = np.linalg.norm(agents[:, :, None] - lms[:, None], axis=-1)
    best = [min(itertools.permutations(range(n)), key=lambda p, c=c: sum(c[a, p[a]] for a in range(n)))[0]
            for c in cost]
    assert assigned_landmark(agents, lms).tolist() == best


def spread_observations(positions, landmarks):
    """The navigation env's own observations [B, N, obs_dim] of worlds with these positions [B, N, 2], [B, L, 2]."""
    b, n = positions.shape[:2]
    env = BatchedSparseSpread(b, SpreadParams(num_agents=n), seed=0)
    env.reset(seed=0)
    state = env.get_state()
    return env.set_state({**state, "positions": positions, "landmarks": landmarks, "velocities": 0 * positions})


def expected_targets(positions, landmarks):
    """Each agent's target from the absolute positions [N, 2], [L, 2]: agent i first, then the others in order."""
    n = len(positions)
    rows = np.stack([positions[[i, *[j for j in range(n) if j != i]]] for i in range(n)])
    return assigned_landmark(rows, np.stack([landmarks] * n)).tolist()


def test_targets_are_read_from_each_agents_own_observation():
    layout = spread_layout(3)
    moved = AGENTS / 20 + np.array([-0.5, 0.3])  # world 1: the agents moved, the landmarks not
    obs = spread_observations(np.stack([AGENTS / 20, moved]), np.stack([LANDMARKS / 20] * 2))
    target, present = assignment_targets(layout, obs)
    assert target.tolist() == [[1, 0, 2], expected_targets(moved, LANDMARKS / 20)] and present.all()
    count = np.array([[2, 2, 2], [3, 3, 3]])  # world 0 holds only agents 0, 1 (and landmarks 0, 1)
    target, present = assignment_targets(layout, obs, count)
    assert target[0].tolist() == [1, 0, -1] and present[0].tolist() == [[True, True, False]] * 3
    assert target[1].tolist() == expected_targets(moved, LANDMARKS / 20) and present[1].all()


def test_a_layout_without_landmarks_is_refused_in_one_line():
    with pytest.raises(ValueError, match="landmarks") as err:
        AssignmentTerm(1.0, tag_layout(TagParams()))
    assert "\n" not in str(err.value)


N = 4
LAYOUT = spread_layout(N)


def fixed_batch(s=32, seed=0):
    """A per-owner batch [N, S, ...] of real navigation observations (random worlds), random actions and rewards."""
    obs = BatchedSparseSpread(N * s, SpreadParams(num_agents=N), seed=seed).reset(seed=seed).reshape(N, s, N, -1)
    rng = np.random.default_rng(seed)
    return {"obs": obs, "next_obs": obs, "act": rng.uniform(-1, 1, (N, s, N, 2)).astype(np.float32),
            "rew": rng.normal(size=(N, s, N)).astype(np.float32)}


def learner(beta=0.0, **kw):
    return MADDPG(N, LAYOUT.obs_dim, 2, hidden=32, seed=0, networks="entity", entity_layout=LAYOUT,
                  assignment_loss=beta, **kw)


def test_off_by_default_computes_nothing_more(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the assignment ran with assignment_loss = 0")

    monkeypatch.setattr(assignment, "assignment_targets", refuse)
    default, off = MADDPG(N, LAYOUT.obs_dim, 2, hidden=32, seed=0, networks="entity", entity_layout=LAYOUT), learner()
    batch = fixed_batch(8)
    for _ in range(3):
        a, b = default.update(batch), off.update(batch)
    assert off.assignment is None and set(a) == set(b) and not any(k.startswith("assignment") for k in b)
    for key, value in default.state_dict()["actor"].items():
        assert torch.equal(value, off.state_dict()["actor"][key])


def test_the_actor_acts_from_the_same_pass_that_gives_the_logits():
    m = learner(1.0)
    x = torch.as_tensor(fixed_batch(8)["obs"][0]).transpose(0, 1)  # [N, B, obs_dim]
    out, logits = m.actor.act_and_attend(x)
    assert torch.equal(out, m.actor(x)) and logits.shape == (N, 8, LAYOUT.num_entities)
    calls = []
    encode = m.actor.encoder.encode
    m.actor.encoder.encode = lambda *a: calls.append(1) or encode(*a)
    m.update(fixed_batch(8))
    assert len(calls) == 1  # one batched actor pass for every owner, with the logits


def test_the_loss_trains_the_attention_toward_the_assignment():
    """Chance is 1/4. The attention pool's landmark logits see the agent and that landmark only (not the other
    agents), so here they learn roughly 'the nearest landmark', which is the target in ~60 % of these worlds; a
    learner that does not back-propagate the loss stays near its start."""
    batch = fixed_batch()
    m, control = learner(5.0, actor_lr=3e-3), learner(0.0, actor_lr=3e-3)
    first = m.update(batch)["assignment_accuracy"].mean()
    for _ in range(120):
        last = m.update(batch)
        control.update(batch)
    assert last["assignment_loss"].mean() < 0.85 * np.log(N)  # the CE of uniform attention is log N
    assert last["assignment_accuracy"].mean() > max(0.45, first + 0.2)
    own = torch.as_tensor(batch["obs"][np.arange(N), :, np.arange(N)])  # [N, S, obs_dim]
    probe = AssignmentTerm(1.0, LAYOUT)
    with torch.no_grad():
        probe.loss(control.actor.act_and_attend(own)[1], own)
    assert probe.last["assignment_accuracy"].mean() < 0.4  # the actor loss alone does not learn it


def test_absent_agents_in_the_learners_rows():
    batch = fixed_batch(8)
    present = np.ones((N, 8, N), bool)
    present[:, 4:, 3] = False  # rows 4..7 hold agents 0..2 only: owner 3 is absent there
    m = learner(1.0)
    out = m.update({**batch, "present": present})
    assert np.isfinite(out["assignment_loss"]).all() and np.isfinite(out["assignment_accuracy"]).all()
    present[3, :, 3] = False  # owner 3 absent from every one of its rows: nothing to learn, accuracy NaN
    present[3, :4, 3] = False
    out = m.update({**batch, "present": present})
    assert out["assignment_loss"][3] == 0 and np.isnan(out["assignment_accuracy"][3])


@pytest.mark.parametrize(("kw", "needs"), [({"networks": "per_agent", "entity_layout": None}, "'entity'"),
                                           ({"entity_pool": "mean"}, "attention"),
                                           ({"entity_nearest": 2}, "entity_nearest = 0")])
def test_the_learner_refuses_what_it_cannot_supervise_in_one_line(kw, needs):
    args = {"networks": "entity", "entity_layout": LAYOUT, **kw}
    with pytest.raises(ValueError, match=needs) as err:
        MADDPG(N, LAYOUT.obs_dim, 2, hidden=32, seed=0, assignment_loss=0.5, **args)
    assert "\n" not in str(err.value) and "maddpg.assignment_loss = 0.5" in str(err.value)


@pytest.mark.parametrize(("path", "sets", "needs"), [
    ("spread_maddpg.toml", [], "maddpg.networks = 'entity'"),
    ("spread_n8.toml", ["maddpg.entity_pool='mean'"], "an attention to supervise"),
    ("tag_maddpg.toml", ["maddpg.networks='entity'"], "env.task = 'spread'"),
    ("spread_n8.toml", ["env.factory='a.b:c'"], "env.task = 'spread'"),
])
def test_the_config_refuses_it_in_one_line_naming_the_field_and_value(path, sets, needs):
    with pytest.raises(ConfigError, match=needs) as err:
        load_config(f"configs/{path}", [*sets, "maddpg.assignment_loss=0.5"])
    message = str(err.value)
    assert "\n" not in message and message.startswith("maddpg.assignment_loss") and message.endswith("got 0.5")


@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_the_weight_is_a_finite_number_at_least_0(value):
    with pytest.raises(ConfigError, match="maddpg.assignment_loss must be a finite number >= 0"):
        load_config("configs/spread_n8.toml", [f"maddpg.assignment_loss={value}"])


def test_the_setting_reaches_the_learner_of_either_runner():
    from cmcl.system import build_maddpg, layout_of

    config = load_config("configs/spread_n8.toml", ["maddpg.assignment_loss=0.5", "maddpg.entity_pool='relational'"])
    for runner in ("inline", "service"):  # both runners build the learner with cmcl.system.build_maddpg
        check_runner_keys(config, runner, overrides=["maddpg.assignment_loss=0.5"])
    assert build_maddpg(config, layout_of(config), seed=0).assignment.weight == 0.5
    assert build_maddpg(load_config("configs/spread_n8.toml"), layout_of(config), seed=0).assignment is None


def test_both_runners_report_the_terms_stats(tmp_path, tiny_config):
    from services.roles.learner import last_losses
    from tests.in_process import train_tiny

    config = tiny_config("maddpg", episodes=6, service=True,
                         sections={"maddpg": {"networks": "entity", "assignment_loss": 1.0}})
    summary, roles = train_tiny(config, tmp_path / "run")  # the inline runner: the service's learner in-process
    n = config.env.spread.num_agents
    losses = roles.learner.report().learner.losses  # the learner's report, per agent (as on the Ray service)
    assert len(losses) == n and all({"assignment", "assignment_accuracy"} <= set(kinds) for kinds in losses.values())
    served = [line for line in summary["metrics_text"].splitlines() if 'kind="assignment"' in line]
    assert len(served) == n  # and its metrics, as the service serves them
    stats = {"critic_loss": np.ones(2), "actor_loss": np.ones(2), "critic_loss_normalised": np.ones(2),
             "assignment_loss": np.array([1.2, 0.0]), "assignment_accuracy": np.array([0.5, np.nan])}
    assert last_losses(stats, 0) == {"critic": 1.0, "actor": 1.0, "critic_normalised": 1.0, "assignment": 1.2,
                                     "assignment_accuracy": 0.5}
    assert "assignment_accuracy" not in last_losses(stats, 1)  # a report's numbers are finite
