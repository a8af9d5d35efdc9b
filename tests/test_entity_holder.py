"""maddpg.entity_holder: each landmark's holder margin as one more entity feature of the entity networks.

The margin's values on hand-built views (torch and its numpy twin), the twins' agreement, that only a landmark's
nearest other agent sets it; the setting loads, is refused in one line where it cannot apply, leaves every input width
as it was when off and adds one entity input when on (learner, targets, entity teachers, entity ICM); the critic's
entity rows end with it in both of its views; the rollout workers' numpy actor acts as the learner's actor, nearest
k included; it trains inline, its checkpoints say it, evaluation rebuilds the same model, and a resume, an evaluation
or a warm start under the other value is refused naming maddpg.entity_holder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from cmcl.config import ConfigError, load_config
from cmcl.envs.entities import spread_layout
from cmcl.learners.maddpg import MADDPG
from cmcl.learners.weights import published_weights
from cmcl.replay.messages import CURIOSITY, DIFFICULTY, Scorer

ROOT = Path(__file__).resolve().parents[1]
N8 = "configs/spread_n8.toml"
HOLDER = "maddpg.entity_holder=true"
OFF = "maddpg.entity_holder=false"  # the N = 8 preset has it on
TYPES = slice(2, 4)  # navigation's type one-hot (landmark, agent) after the 2 raw features
REFUSED = "maddpg.entity_holder = true and this config has false"


def _torch_margin(entities: np.ndarray, mask: np.ndarray) -> np.ndarray:
    from cmcl.learners.entity.nets import holder_margin

    return holder_margin(torch.from_numpy(entities), torch.from_numpy(mask), TYPES).numpy()


def _numpy_margin(entities: np.ndarray, mask: np.ndarray) -> np.ndarray:
    from cmcl.rollout.policy import holder_margin

    return holder_margin(entities, mask, TYPES)


TWINS = pytest.mark.parametrize("margin", [_torch_margin, _numpy_margin], ids=["torch", "numpy"])


def _view(*rows: tuple[float, float, str]) -> np.ndarray:
    """Entity rows [dx, dy, landmark, agent] float32[E, 4] from (dx, dy, "l" or "a")."""
    return np.array([[x, y, float(kind == "l"), float(kind == "a")] for x, y, kind in rows], np.float32)


@TWINS
def test_the_margin_of_a_hand_built_view(margin):
    # the viewer at the origin: landmark 0 has another agent right next to it (held), landmark 1 is the viewer's,
    # landmark 2 and agent B are absent (B, next to landmark 1, is not counted), agents' rows read 0
    view = _view((0.5, 0.0, "l"), (0.0, 0.1, "l"), (0.3, 0.3, "l"), (0.6, 0.0, "a"), (0.0, 0.12, "a"),
                 (-1.0, 0.0, "a"))
    mask = np.array([[True, True, False, True, False, True],
                     [True, True, False, False, False, False]])  # row 1: no other agent present
    out = margin(np.stack([view, view]), mask)
    assert out.shape == (2, 6, 1) and out.dtype == np.float32
    np.testing.assert_allclose(out[0, :, 0], [0.1 - 0.5, np.sqrt(0.6**2 + 0.1**2) - 0.1, 0, 0, 0, 0], atol=1e-6)
    assert out[0, 0, 0] < 0 < out[0, 1, 0]  # held by another agent; the viewer's own
    np.testing.assert_array_equal(out[1, :, 0], [2.0, 2.0, 0, 0, 0, 0])  # alone: HOLDER_ALONE


@TWINS
def test_only_a_landmarks_nearest_other_agent_sets_its_margin(margin):
    # landmark at (0.5, 0), agent A 0.1 from it; agent F moved over a grid: the margin changes iff F is nearer
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1, 1, 21)), -1).reshape(-1, 2)
    views = np.repeat(_view((0.5, 0.0, "l"), (0.6, 0.0, "a"), (-1.0, -1.0, "a"))[None], len(grid), 0)
    views[:, 2, :2] = grid
    out = margin(views, np.ones(views.shape[:2], bool))[:, 0, 0]
    nearer = np.linalg.norm(grid - [0.5, 0.0], axis=-1) < 0.1 - 1e-6
    assert nearer.sum() >= 1 and (~nearer).sum() > 400
    np.testing.assert_allclose(out[~nearer], 0.1 - 0.5, atol=1e-6)  # F far: A holds it, whatever F does
    np.testing.assert_allclose(out[nearer], np.linalg.norm(grid[nearer] - [0.5, 0.0], axis=-1) - 0.5, atol=1e-6)
    assert (out[nearer] < 0.1 - 0.5).all()


def test_the_torch_and_numpy_twins_agree_and_read_only_positions_and_types():
    layout = spread_layout(6)
    rng = np.random.default_rng(4)
    _, ents, _ = layout.split(rng.uniform(-1.5, 1.5, size=(3, 16, 6, layout.obs_dim)).astype(np.float32))
    mask = rng.random(ents.shape[:-1]) < 0.7
    ours, theirs = _numpy_margin(ents, mask), _torch_margin(np.ascontiguousarray(ents), mask)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-6)
    assert ours.shape == (3, 16, 6, 11, 1) and (ours[..., 6:, 0] == 0).all()  # the 5 agent slots read 0
    assert (ours[..., :6, 0][~mask[..., :6]] == 0).all() and (ours[..., :6, 0][mask[..., :6]] != 0).mean() > 0.99
    extra = np.concatenate([ents, rng.normal(size=(*ents.shape[:-1], 5)).astype(np.float32)], -1)  # critic rows
    np.testing.assert_array_equal(_numpy_margin(extra, mask), ours)


def test_the_margin_from_the_layouts_slots_is_the_generic_margin():
    """The networks' fast path (landmark x agent distances in the layout's static slots) gives the generic margin."""
    from cmcl.learners.entity.holder import holder_margin, holder_margin_of_slots, holder_slots

    layout = spread_layout(5)
    rng = np.random.default_rng(7)
    _, ents, _ = layout.split(rng.uniform(-1.5, 1.5, size=(4, 9, 5, layout.obs_dim)).astype(np.float32))
    ents, types = torch.from_numpy(np.ascontiguousarray(ents)), slice(2, 4)
    for keep in (0.0, 0.5, 1.0):  # no agent present anywhere, some, all
        mask = torch.from_numpy(rng.random(ents.shape[:-1]) < 0.7)
        mask[..., 5:] &= torch.from_numpy(rng.random(mask[..., 5:].shape) < keep)
        fast = holder_margin_of_slots(ents, mask, *holder_slots(layout))
        torch.testing.assert_close(fast, holder_margin(ents, mask, types), rtol=0, atol=1e-6)
    landmarks, agents = holder_slots(layout)
    assert landmarks.tolist() == [0, 1, 2, 3, 4] and agents.tolist() == [5, 6, 7, 8]


@pytest.mark.parametrize("nearest", [0, 1, 3])
@pytest.mark.parametrize("pool", ["attention", "mean", "relational"])
@pytest.mark.parametrize("noise", [0.0, 0.1])
def test_the_numpy_actor_acts_as_the_learners_actor(noise, pool, nearest):
    from cmcl.rollout.policy import numpy_policy

    for layout in (spread_layout(5), spread_layout(5, agent_tags=True), spread_layout(2)):
        n, od = layout.num_agents, layout.obs_dim
        maddpg = MADDPG(n, od, seed=3, networks="entity", entity_layout=layout, entity_pool=pool,
                        entity_nearest=nearest, entity_holder=True)
        obs = np.random.default_rng(0).normal(scale=0.7, size=(32, n, od)).astype(np.float32)
        policy = numpy_policy(published_weights(maddpg)["actor"], entities=layout, nearest=nearest, holder=True)
        assert policy.holder
        ours = policy.act(obs, noise, rng=np.random.default_rng(7))
        np.testing.assert_allclose(ours, maddpg.act(obs, noise, rng=np.random.default_rng(7)), atol=1e-5)


@pytest.mark.parametrize("nearest", [0, 2])
def test_the_numpy_actor_acts_as_the_learners_actor_on_rows_of_fewer_agents(nearest):
    """Rows carried from fewer agents (run.carry_replay): the absent agents hold no landmark."""
    from cmcl.rollout.policy import numpy_policy

    layout = spread_layout(5)
    maddpg = MADDPG(5, layout.obs_dim, seed=1, networks="entity", entity_layout=layout, entity_nearest=nearest,
                    entity_holder=True)
    rng = np.random.default_rng(2)
    obs = rng.normal(scale=0.7, size=(40, 5, layout.obs_dim)).astype(np.float32)
    count = np.repeat(rng.integers(1, 6, size=(40, 1)), 5, axis=1)  # [B, N]: the first count agents present
    policy = numpy_policy(published_weights(maddpg)["actor"], entities=layout, nearest=nearest, holder=True)
    with torch.no_grad():
        theirs = maddpg.actor(torch.from_numpy(obs).transpose(0, 1), count=torch.from_numpy(count.T)).numpy()
    np.testing.assert_allclose(policy.mean_action(obs, count), theirs.transpose(1, 0, 2), atol=1e-5)


def test_the_numpy_actor_refuses_weights_of_the_other_setting_and_the_margin_outside_navigation():
    from cmcl.envs.entities import tag_layout
    from cmcl.envs.params import TagParams
    from cmcl.learners.entity.nets import EntityActor
    from cmcl.rollout.policy import numpy_policy

    layout = spread_layout(3)
    for holder in (False, True):
        weights = published_weights(MADDPG(3, layout.obs_dim, seed=0, networks="entity", entity_layout=layout,
                                           entity_holder=holder))["actor"]
        with pytest.raises(ValueError, match="maddpg.entity_holder"):
            numpy_policy(weights, entities=layout, holder=not holder)
    with pytest.raises(ValueError, match="holder margin needs entity actor weights"):
        numpy_policy(published_weights(MADDPG(3, layout.obs_dim, seed=0))["actor"], holder=True)
    with pytest.raises(ValueError, match="navigation's entities"):
        EntityActor(tag_layout(TagParams()), 2, 16, torch.Generator().manual_seed(0), holder=True)


@pytest.mark.parametrize("counted", [False, True])
def test_the_critics_entity_rows_end_with_the_margin_of_the_agents_view_in_both_views(counted):
    from cmcl.learners.entity.nets import EntityCritic, holder_margin

    n, act_dim, rows = 4, 2, 24
    layout = spread_layout(n)
    critic = EntityCritic(layout, act_dim, 16, torch.Generator().manual_seed(0), holder=True)
    gen = torch.Generator().manual_seed(1)
    obs = torch.randn(1, rows, n, layout.obs_dim, generator=gen)
    act = torch.rand(1, rows, n, act_dim, generator=gen) * 2 - 1
    count = torch.randint(1, n + 1, (1, rows), generator=gen) if counted else None
    q = {}
    for agent in range(n):
        _, ents, mask = layout.split(obs[0, :, agent:agent + 1], [agent])  # agent's own view [R, 1, E, F]
        if counted:
            mask = layout.present_mask(count[0, :, None], [agent])
        expected = holder_margin(ents, mask, TYPES)[:, 0]  # [R, E, 1]
        for fused in (True, False):  # CriticViews.gather and CriticViews.reference
            critic.encoder.fused = fused
            own, rows_, _ = critic._views(obs, act, torch.full((1, rows), agent), count)
            assert rows_.shape[-1] == layout.entity_dim + layout.own_dim + act_dim + 1
            torch.testing.assert_close(rows_[0, ..., -1:], expected, rtol=0, atol=0)
            q[fused] = critic.q_agent(obs, act, torch.full((1, rows), agent), count)
        torch.testing.assert_close(q[True], q[False], rtol=0, atol=1e-5)


@pytest.mark.parametrize(("path", "sets", "message"), [
    ("configs/spread_maddpg.toml", [HOLDER],
     "maddpg.entity_holder needs maddpg.networks = 'entity' (maddpg.networks = 'per_agent' here), got True"),
    (N8, ["maddpg.networks='shared'", HOLDER],
     "maddpg.entity_holder needs maddpg.networks = 'entity' (maddpg.networks = 'shared' here), got True"),
    ("configs/tag_maddpg.toml", ["maddpg.networks='entity'", HOLDER],
     "maddpg.entity_holder needs env.task = 'spread' (a landmark's holder margin; env.task = 'tag' here), got True"),
    (N8, ["env.factory='a.b:c'", HOLDER],
     "maddpg.entity_holder needs env.task = 'spread' (a landmark's holder margin; env.task = 'spread' with "
     "env.factory here), got True"),
])
def test_the_config_refuses_what_cannot_apply_in_one_line_naming_the_field_and_value(path, sets, message):
    with pytest.raises(ConfigError) as err:
        load_config(path, sets)
    assert str(err.value) == message


def test_the_command_line_refuses_it_for_other_networks_with_exit_2(tmp_path):
    from tests.test_entity_nearest import train_per_agent_with

    code, lines = train_per_agent_with(HOLDER, tmp_path)
    assert code == 2 and len(lines) == 1 and "maddpg.entity_holder needs" in lines[0], lines
    assert not (tmp_path / "run").exists()


def test_off_by_default_on_in_the_n8_preset_off_no_width_changes_on_every_entity_network_reads_one_more():
    from cmcl.config.learning import MADDPGConfig
    from cmcl.system import build_icm, build_maddpg, build_teachers, layout_of

    assert MADDPGConfig().entity_holder is False and load_config(N8).maddpg.entity_holder is True
    sets = ["teams.agent.algorithm='cmcl'", "teachers.networks='entity'", "icm.networks='entity'"]
    for on in (False, True):
        config = load_config(N8, sets + [HOLDER if on else OFF])
        layout = layout_of(config)
        f, own_in = layout.entities.entity_dim, layout.entities.own_dim + layout.act_dim
        maddpg = build_maddpg(config, layout, seed=0)
        assert maddpg.entity_holder is on and maddpg.state_dict()["entity_holder"] is on
        width = {name: getattr(maddpg, name).encoder.entity.weight.shape[1]
                 for name in ("actor", "target_actor", "critic", "target_critic")}
        assert width == {"actor": f + on, "target_actor": f + on, "critic": f + own_in + on,
                         "target_critic": f + own_in + on}
        assert build_teachers(config, layout, seed=0).net.encoder.entity.weight.shape[1] == f + own_in + on
        assert build_icm(config, layout, seed=0).phi.encoder.entity.weight.shape[1] == f + on


def test_the_rollout_workers_numpy_actor_reads_the_margin():
    from cmcl.system import build_maddpg
    from services.roles.rollout import RolloutWorker

    worker = RolloutWorker(load_config(N8, [HOLDER, "env.num_envs=2"]).to_dict(), worker_id=0, seed=1)
    maddpg = build_maddpg(worker.config, worker.layout, seed=0)
    policy = worker._numpy_policy(published_weights(maddpg)["actor"])
    assert policy.holder
    np.testing.assert_allclose(policy.act(worker.obs, 0.0), maddpg.act(worker.obs, 0.0), atol=1e-5)


def test_every_service_role_reads_the_margin():
    """The service's roles in-process (tests/in_process.py): the rollout worker's numpy actor, the learner, the
    teachers (and their target networks) and the entity ICM read the margin; one round of the data flow runs."""
    from cmcl.rollout.policy import NumpyEntityPolicy
    from tests.in_process import in_process_config, roles

    cfg = in_process_config("cmcl", maddpg={"networks": "entity", "entity_holder": True},
                            service={"score_rows_per_call": 360}, icm={"networks": "entity"},
                            teachers={"networks": "entity"})
    replay, learner, worker, teachers, icm = roles(cfg)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    assert isinstance(worker.policy, NumpyEntityPolicy) and worker.policy.holder
    assert learner.maddpg.actor.holder and learner.maddpg.critic.holder and icm.icm.phi.holder
    assert teachers[0].targets.target_critic.holder and teachers[0].teachers.net.holder
    learner.update(replay.sample(4)[0])
    published = learner.publish()
    chunk, _ = worker.rollout(published)
    assert worker.version == published["version"] and worker.policy.holder and np.isfinite(chunk.act).all()
    work, _ = replay.work(Scorer(DIFFICULTY, (0,)), 2)
    assert np.isfinite(teachers[0].score(work, published)[0].values).all()
    work, _ = replay.work(Scorer(CURIOSITY), 2)
    assert np.isfinite(icm.score(work)[0].values).all()


def test_a_state_records_it_and_one_of_the_other_value_is_refused_in_one_line():
    layout = spread_layout(3)
    build = lambda holder: MADDPG(3, layout.obs_dim, seed=0, networks="entity", entity_layout=layout,  # noqa: E731
                                  entity_holder=holder)
    on, off = build(True).state_dict(), build(False).state_dict()
    build(True).load_state_dict(on)
    with pytest.raises(ValueError, match="^checkpoint maddpg without 'entity_holder': written by an older version"):
        build(False).load_state_dict({k: v for k, v in off.items() if k != "entity_holder"})
    for holder, state, saved in ((False, on, "true"), (True, off, "false")):
        with pytest.raises(ValueError) as err:
            build(holder).load_state_dict(state)
        message = str(err.value)
        assert message.startswith(f"checkpoint maddpg was trained with maddpg.entity_holder = {saved} and this "
                                  f"config has {'true' if holder else 'false'}") and "\n" not in message
        assert message.endswith(f"set maddpg.entity_holder = {saved}")


def test_it_trains_inline_and_evaluation_rebuilds_the_same_model_while_the_other_value_is_refused(tmp_path, capsys):
    from cmcl.run.evaluate import load_policy
    from cmcl.run.evaluate import main as evaluate
    from cmcl.run.flags import check_warm_start
    from cmcl.run.rundir import RunDirectory
    from services.launch import train_in_process
    from services.roles.learner import Learner
    from tests.evaluation_output import evaluation_json

    # two rounds of the 16 worlds, two updates in the second (tests/test_entity_nearest.py's smoke)
    run = tmp_path / "run"
    config = load_config(N8, [HOLDER, f"run.dir={run}", "run.init_from=", "run.episodes=32", "maddpg.warmup=480",
                              "maddpg.update_every=240", "run.max_seconds=0"])
    _, roles = train_in_process(config, RunDirectory.create(run, config))  # the inline runner
    maddpg = roles.learner.maddpg
    assert maddpg.updates > 0 and maddpg.actor.holder and maddpg.target_critic.holder
    policy = RunDirectory.open(run).newest_policy()
    assert policy.state["maddpg"]["entity_holder"] is True
    assert "entity_holder = true" in (run / "config.toml").read_text()

    capsys.readouterr()
    assert evaluate([str(run), "--episodes", "4", "--no-gif"]) == 0  # the run's config.toml rebuilds the margin
    assert evaluation_json(capsys.readouterr().out)["policy"] == "trained"
    rebuilt = load_policy(config, policy)
    obs = np.random.default_rng(0).normal(scale=0.7, size=(8, 8, rebuilt.obs_dim)).astype(np.float32)
    np.testing.assert_array_equal(rebuilt.act(obs, 0.0), maddpg.act(obs, 0.0))

    off = load_config(N8, [OFF])
    with pytest.raises(ValueError, match=f"checkpoint maddpg was trained with {REFUSED}"):  # evaluation
        load_policy(off, policy)
    with pytest.raises(ValueError, match=f"checkpoint maddpg was trained with {REFUSED}"):  # a resume's restore
        Learner(off, 0, str(RunDirectory.open(run).service_paths()["learner"]))  # the learner role restores it
    check_warm_start(load_config(N8, [HOLDER, f"run.init_from={run}"]))  # the same value: accepted
    with pytest.raises(ConfigError, match=f"run.init_from=.*: maddpg was trained with {REFUSED}") as err:
        check_warm_start(load_config(N8, [OFF, f"run.init_from={run}"]))
    assert "\n" not in str(err.value)
