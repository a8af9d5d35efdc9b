"""Typed configuration: presets, TOML loading, overrides and validation errors that name the field."""

import math
import os
import tomllib
from pathlib import Path

import pytest

from cmcl.config import ConfigError, config_from_dict, dump_toml, load_config, load_stored_config, preset

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
FIXTURES = Path(__file__).resolve().parent / "fixtures"


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_config_loads(path):
    config = load_config(path)
    assert config.run.episodes >= 1
    assert set(config.teams) == ({"agent"} if config.env.task == "spread" else {"predator", "prey"})


@pytest.mark.parametrize("algorithm", ["maddpg", "per", "acl", "cmcl"])
def test_shipped_files_match_presets(algorithm):
    spread = load_config(CONFIGS / f"spread_{algorithm}.toml")
    assert spread.teams == preset(algorithm, "spread").teams
    tag = load_config(CONFIGS / f"tag_{algorithm}.toml")
    assert tag.teams == preset(algorithm, "tag", opponent="maddpg").teams


def test_table1_defaults():
    config = preset("cmcl")
    assert (config.maddpg.gamma, config.maddpg.actor_lr, config.maddpg.critic_lr) == (0.99, 1e-3, 1e-3)
    assert (config.maddpg.tau, config.maddpg.batch_size, config.maddpg.hidden) == (0.01, 128, 64)
    assert (config.replay.capacity, config.curriculum.lam0, config.env.episode_length) == (5000, 0.1, 30)
    assert config.run.episodes == 20000 and config.maddpg.exploration_std == 0.1
    assert config.curriculum_stride() == pytest.approx(3.0e-6)


def test_team_semantics_per_algorithm():
    teams = {a: preset(a).teams["agent"] for a in ("maddpg", "per", "acl", "cmcl")}
    assert [t.uses_teachers for t in teams.values()] == [False, False, True, True]
    assert [t.uses_icm for t in teams.values()] == [False, False, False, True]
    assert [t.importance_weights for t in teams.values()] == [False, True, False, False]
    assert teams["acl"].effective_eta == 0.0 and teams["cmcl"].effective_eta == 0.5


def test_predators_and_prey_can_differ():
    config = preset("cmcl", "tag", opponent="per")
    assert config.teams["predator"].algorithm == "cmcl" and config.teams["prey"].algorithm == "per"


def test_overrides_set_nested_values():
    config = load_config(CONFIGS / "spread_cmcl.toml", ["run.episodes=40", "run.dir=runs/smoke",
                                                        "teams.agent.eta=0.1", "maddpg.discrete=true"])
    assert config.run.episodes == 40 and config.run.dir == "runs/smoke"
    assert config.teams["agent"].eta == 0.1 and config.maddpg.discrete is True


@pytest.mark.parametrize(
    ("override", "fragment"),
    [
        ("maddpg.gamma=2", "maddpg.gamma"),
        ("maddpg.gammma=0.9", "maddpg.gammma"),
        ("replay.capacity=0", "replay.capacity"),
        ("run.episodes=1.5", "run.episodes"),
        ("teams.agent.algorithm=dqn", "teams.agent.algorithm"),
        ("teams.agent.eta=-1", "teams.agent.eta"),
        ('teams.agent.priority_sharing="team_mean"', "teams.agent.priority_sharing"),
        ("curriculum.lam0=0", "curriculum.lam0"),
        ("env.task=tag", "teams"),
        ("nonsense.key=1", "nonsense"),
        ("env.agent_radius=0.7", "env.agent_radius"),  # a world field's own range check, under its TOML key
        ("env.num_predators=0", "env.num_predators"),
        ("env.tag_shared_reward=1", "env.tag_shared_reward"),
        ("env.capture_reward=\"x\"", "env.capture_reward"),
        ("env.spread.agent_radius=0.1", "env.spread"),  # the world is written flat in [env]
        ("noequals", "section.key=value"),
    ],
)
def test_bad_values_name_the_field(override, fragment):
    with pytest.raises(ConfigError, match=fragment.replace(".", r"\.")):
        load_config(CONFIGS / "spread_cmcl.toml", [override])


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "absent.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[run\nepisodes = ")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(broken)


def test_flat_env_keys_set_the_worlds_one_home():
    """`[env] agent_radius = ...` and the other world keys land in EnvConfig.spread / .tag (cmcl.envs.params), the
    object the twins and the PettingZoo envs take; the run's navigation reward is individual (§6.1, revised)."""
    from cmcl.envs.params import SpreadParams, TagParams

    config = load_config(CONFIGS / "tag_cmcl.toml", ["env.cover_radius=0.075", "env.prey_radius=0.03",
                                                     "env.tag_shared_reward=true", "env.shared_reward=true"])
    assert config.env.spread == SpreadParams(cover_radius=0.075, shared_reward=True)
    assert config.env.tag == TagParams(prey_radius=0.03, shared_reward=True) and config.env.world is config.env.tag
    assert preset("cmcl").env.spread == SpreadParams(shared_reward=False) and SpreadParams().shared_reward
    env = config.to_dict()["env"]
    assert (env["cover_radius"], env["prey_radius"], env["tag_shared_reward"]) == (0.075, 0.03, True)
    assert config_from_dict(config.to_dict()) == config


def test_dump_round_trip():
    config = preset("per", "tag", opponent="acl")
    assert config_from_dict(tomllib.loads(dump_toml(config))) == config


def test_paper_presets_keep_the_papers_schedule_and_nothing_else():
    paper = sorted((CONFIGS / "paper").glob("*.toml"))
    assert [p.stem for p in paper] == [f"{t}_{a}" for t in ("spread", "tag") for a in ("acl", "cmcl", "maddpg", "per")]
    for path in paper:
        ours, theirs = load_config(CONFIGS / path.name).to_dict(), load_config(path).to_dict()
        assert theirs["maddpg"]["update_every"] == 1 and theirs["teachers"]["steps_per_update"] == 1.0
        assert theirs["icm"]["steps_per_update"] == 1.0 and theirs["teachers"]["fit_batch"] == "per_agent"
        # the whole buffer rescored every 30 updates (§3.8): a teacher call comes every fit_steps_per_call /
        # steps_per_update updates, and rescores that many updates' share of the buffer
        service, updates_per_teacher_call = theirs["service"], theirs["service"]["fit_steps_per_call"] / 1.0
        assert service["score_rows_per_call"] == math.ceil(theirs["replay"]["capacity"] / 30) * \
            updates_per_teacher_call
        for section, keys in (("maddpg", ("update_every",)), ("teachers", ("steps_per_update", "fit_batch")),
                              ("icm", ("steps_per_update",)), ("service", ("score_rows_per_call",))):
            for key in keys:
                ours[section].pop(key), theirs[section].pop(key)
        ours["run"].pop("dir"), theirs["run"].pop("dir")
        assert ours == theirs, path


@pytest.mark.parametrize(("old", "new"), [
    ("teachers.difficulty_norm=max", "teams.<team>.priority.difficulty_norm (one per team)"),
    ("teachers.difficulty_transform=permuted", "teams.<team>.priority.difficulty_transform (one per team)"),
    ("teachers.difficulty_error=abs", "teams.<team>.priority.difficulty_error (one per team)"),
    ("icm.cp_input=raw", "teams.<team>.priority.cp_input (one per team)"),
    ("replay.alpha=0.5", "teams.<team>.priority.alpha (one per team)"),
    ("teams.agent.alpha=0.5", "teams.agent.priority.alpha"),
    ("teams.agent.uniform_floor=0.2", "teams.agent.priority.uniform_floor"),
])
def test_a_moved_key_is_refused_naming_the_key_that_replaced_it(old, new, tmp_path):
    """On the command line and in a file alike: one line naming the old key, its value and the new key."""
    key, value = old.split("=")
    expected = f"{key} moved to {new}; set that instead, got "
    with pytest.raises(ConfigError) as err:
        load_config(None, [old])
    assert str(err.value).startswith(expected) and value in str(err.value) and "\n" not in str(err.value)
    section, name = key.rsplit(".", 1)
    path = tmp_path / "old.toml"
    path.write_text(f"[{section}]\n{name} = {value if value[0].isdigit() else repr(value)}\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(expected)


def test_a_stored_config_from_before_the_priority_tables_is_read_with_its_keys_moved():
    """A run directory's config.toml written before [teams.<team>.priority] (tests/fixtures): read as a stored
    config (resume, evaluate), every old value lands in the new table of each team it applied to; the team's own α
    wins over the global replay.alpha, as it did; the keys removed since (run.log_every, run.checkpoint_every,
    teachers.rescore_rows_per_update: cmcl.config.moved.REMOVED) are dropped. Read as user input, it is refused."""
    stored = FIXTURES / "config_before_priority.toml"
    old = tomllib.loads(stored.read_text())
    assert {"log_every", "checkpoint_every"} <= set(old["run"]) and "rescore_rows_per_update" in old["teachers"]
    config = load_stored_config(stored)
    predator, prey = config.teams["predator"].priority, config.teams["prey"].priority
    for team in (predator, prey):
        assert (team.difficulty_norm, team.difficulty_transform, team.difficulty_error, team.cp_input) == \
            ("max", "reversed", "abs", "raw")
    assert (predator.alpha, prey.alpha) == (0.8, 0.3) and (predator.uniform_floor, prey.uniform_floor) == (0.1, 0.0)
    assert config.teams["prey"].effective_alpha() == 0.3 and config.run.dir == "runs/tag_before_priority"
    assert load_stored_config(stored, ["teams.prey.priority.alpha=0.5"]).teams["prey"].priority.alpha == 0.5
    with pytest.raises(ConfigError, match=r"^teachers\.difficulty_norm moved to"):
        load_stored_config(stored, ["teachers.difficulty_norm=rank"])  # an override is the user's: the new keys
    with pytest.raises(ConfigError, match=r"^run\.log_every was removed \(both runners log a progress row every "):
        load_config(stored)  # the first refusal of user input: a removed key, before the moved ones
    again = tomllib.loads(dump_toml(config))  # written back, it has only the new keys
    assert "alpha" not in again["replay"] and "difficulty_norm" not in again["teachers"]
    assert not {"log_every", "checkpoint_every"} & set(again["run"]) and "rescore_rows_per_update" not in \
        again["teachers"]
    assert config.service.checkpoint_every_s == 60.0 and config.service.score_rows_per_call == 1024  # kept
    assert config_from_dict(again) == config and load_stored_config(stored) == config


def test_a_stored_config_without_moved_keys_reads_as_it_is(tmp_path):
    path = tmp_path / "config.toml"
    config = load_config(CONFIGS / "tag_cmcl.toml", ["teams.predator.priority.difficulty_norm=max"])
    path.write_text(dump_toml(config))
    assert load_stored_config(path) == config


def test_a_run_dir_under_home_is_the_users_home_not_a_folder_named_tilde():
    """`--set run.dir=~/runs/x` reaches the program unexpanded (a shell expands ~ after = only in assignments); before
    (found by hand 2026-12-06) it made a folder named "~" in the working directory."""
    config = load_config(None, ("run.dir=~/runs/x", "run.init_from=~/runs/y"))
    assert config.run.dir == os.path.expanduser("~/runs/x") and not config.run.dir.startswith("~")
    assert config.run.init_from == os.path.expanduser("~/runs/y")
    assert load_config(None, ("run.dir=runs/~x",)).run.dir == "runs/~x"  # a ~ inside a name is the name's
