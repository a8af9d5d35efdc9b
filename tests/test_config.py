"""Typed configuration: presets, TOML loading, overrides and validation errors that name the field."""

import math
import os
import re
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


@pytest.mark.parametrize("old", ["teachers.difficulty_norm=max", "replay.alpha=0.5", "teams.agent.alpha=0.5",
                                 "run.log_every=10"])
def test_a_key_of_an_older_layout_is_an_unknown_key(old, tmp_path):
    """On the command line and in a file alike: one line naming the key."""
    key, value = old.split("=")
    with pytest.raises(ConfigError, match=rf"^unknown key {re.escape(key)}\b") as err:
        load_config(None, [old])
    assert "\n" not in str(err.value)
    section, name = key.rsplit(".", 1)
    path = tmp_path / "old.toml"
    path.write_text(f"[{section}]\n{name} = {value if value[0].isdigit() else repr(value)}\n")
    with pytest.raises(ConfigError, match=rf"^unknown key {re.escape(key)}\b"):
        load_config(path)


def test_a_stored_config_of_an_older_layout_is_refused_naming_the_key_and_the_last_commit_that_reads_it(tmp_path):
    """A run directory's config.toml written before [teams.<team>.priority] (tests/fixtures): one line naming the
    file, the first key this version does not know and the commit that reads it; an unknown key of an override is
    the user's, refused as such."""
    from cmcl.replay.snapshot import LAST_READER

    stored = FIXTURES / "config_before_priority.toml"
    with pytest.raises(ConfigError) as err:
        load_stored_config(stored)
    assert re.fullmatch(rf"{re.escape(str(stored))}: unknown key [a-z_]+\.[a-z_]+: written by an older version; "
                        rf"commit {LAST_READER} is the last that reads it", str(err.value)), err.value
    current = tmp_path / "config.toml"
    current.write_text(dump_toml(load_config(CONFIGS / "tag_cmcl.toml")))
    with pytest.raises(ConfigError, match=r"^unknown key teachers\.difficulty_norm \(known"):
        load_stored_config(current, ["teachers.difficulty_norm=rank"])


def test_a_stored_config_reads_as_it_is(tmp_path):
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
