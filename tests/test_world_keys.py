"""With env.factory the built-in worlds' keys are not read (cmcl.config.world_keys): one set by --set is refused in one
line, one in the config file is named in a note, one at its default passes unnoticed. Before (found by hand
2026-12-06): `--set env.num_agents=3` with env.factory trained the factory's environment as it was, silently."""

from __future__ import annotations

import pytest

from cmcl.config import ConfigError, apply_overrides, config_from_dict
from cmcl.config.world_keys import check_world_keys
from tests.test_refusals import QUICK, TEAMS_ENV, assert_one_line_refusal, run_cli

FACTORY = {"env": {"factory": "tests.team_env:parallel_env"}}


def resolved(file_data, overrides=()):
    return config_from_dict(apply_overrides(file_data, list(overrides)))


@pytest.mark.parametrize(("override", "named"), [("env.num_agents=3", "env.num_agents"),
                                                 ("env.cover_radius=0.2", "env.cover_radius"),
                                                 ("env.tag_shared_reward=true", "env.tag_shared_reward"),
                                                 ("env.task=tag", "env.task")])
def test_a_world_key_set_with_a_factory_is_refused_naming_it(override, named):
    with pytest.raises(ConfigError) as refused:
        check_world_keys(resolved(FACTORY, [override]), FACTORY, [override])
    assert str(refused.value).startswith(f"{named} describes the built-in worlds, which env.factory "
                                         "'tests.team_env:parallel_env' replaces"), refused.value


def test_world_keys_in_the_file_are_named_in_a_note_and_defaults_pass():
    data = {"env": {**FACTORY["env"], "num_agents": 6, "cover_radius": 0.2}}
    notes = []
    check_world_keys(resolved(data), data, ["env.episode_length=10"], note=notes.append)
    assert notes == ["note: with env.factory 'tests.team_env:parallel_env' the config file's env.num_agents = 6; "
                     "env.cover_radius = 0.2 describe the built-in worlds and are not read"]
    notes.clear()
    at_default = {"env": {**FACTORY["env"], "num_agents": 4}}  # the default: nothing to say
    check_world_keys(resolved(at_default), at_default, ["env.task=spread"], note=notes.append)
    assert notes == []


def test_without_a_factory_world_keys_are_the_worlds():
    check_world_keys(resolved({}, ["env.num_agents=3"]), {}, ["env.num_agents=3"], note=pytest.fail)


def test_the_command_line_refuses_it_before_the_run_directory(tmp_path):
    run_dir = tmp_path / "run"
    done = run_cli("train", "--runner", "inline", "--set", TEAMS_ENV, "--set", "env.num_agents=3", "--set",
                   f"run.dir={run_dir}", *QUICK)
    assert_one_line_refusal(done, "env.num_agents describes the built-in worlds", "got 3")
    assert not run_dir.exists()
