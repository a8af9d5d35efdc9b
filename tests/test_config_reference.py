"""The configuration reference (`python -m cmcl config`, docs/CONFIG.md): every field documented, from the fields'
own documentation, the allowed range in the words of the error a bad value gets, and the page current."""

import dataclasses
import re
from pathlib import Path

import pytest

from cmcl.__main__ import main
from cmcl.config import TASKS, Config, ConfigError, EnvConfig, PriorityConfig, TeamConfig, load_config
from cmcl.config.env import WORLD_KEYS
from cmcl.config.reference import MARKDOWN_COMMAND, reference
from cmcl.envs.params import SpreadParams, TagParams
from cmcl.field_docs import MEANING
from cmcl.replay.registry import REGISTRY

ROOT = Path(__file__).resolve().parents[1]
# every section of a run but [env] (its worlds' keys are flat), by its dataclass, and the teams' tables (a team's
# [teams.<team>.priority] table its own section)
SECTIONS = {**{f.name: type(getattr(Config(), f.name)) for f in dataclasses.fields(Config) if f.name not in
               ("env", "teams")}, "teams": TeamConfig, "teams.priority": PriorityConfig}


def test_config_md_is_current(capsys):
    """docs/CONFIG.md is what `python -m cmcl config --markdown` prints now; regenerate it when a field changes."""
    assert main(["config", "--markdown"]) == 0
    assert capsys.readouterr().out == (ROOT / "docs" / "CONFIG.md").read_text(), f"stale: run `{MARKDOWN_COMMAND}`"


def test_every_dataclass_field_appears_with_a_meaning():
    """Every field of every section (and of both worlds, under their flat [env] keys) is a key of the reference,
    with a non-empty meaning and allowed range, and nothing else is."""
    docs = reference()
    assert list(docs) == ["env", *SECTIONS]
    # a team's table also holds every registered rule's own options (Rule.options), each marked as that rule's
    rule_options = [f.name for rule in REGISTRY.values() for f in dataclasses.fields(rule.options)]
    for name, cls in SECTIONS.items():
        assert [k.key for k in docs[name].keys] == [f.name for f in dataclasses.fields(cls)
                                                    if not dataclasses.is_dataclass(getattr(cls(), f.name))] + (
            rule_options if name == "teams" else []), name
    env_fields = [f.name for f in dataclasses.fields(EnvConfig) if f.name not in TASKS]
    assert sorted(k.key for k in docs["env"].keys) == sorted([*env_fields, *WORLD_KEYS])
    for cls in [*SECTIONS.values(), EnvConfig, SpreadParams, TagParams]:
        for f in dataclasses.fields(cls):
            assert f.metadata.get(MEANING, "").strip(), f"{cls.__name__}.{f.name} has no meaning"
    for section in docs.values():
        assert section.summary
        for key in section.keys:
            assert key.meaning.strip() and key.allowed.startswith("must ") and key.default, (section.table, key)


@pytest.mark.parametrize(("override", "key"), [
    ("maddpg.gamma=2", "maddpg.gamma"), ("maddpg.tau=0", "maddpg.tau"), ("replay.capacity=0", "replay.capacity"),
    ("teams.agent.priority.alpha=-1", "teams.agent.priority.alpha"), ("curriculum.lam0=0", "curriculum.lam0"),
    ("teams.agent.priority.uniform_floor=1", "teams.agent.priority.uniform_floor"),
    ("teams.agent.priority.cp_input=x", "teams.agent.priority.cp_input"),
    ("teachers.num_folds=1", "teachers.num_folds"), ("icm.lr=0", "icm.lr"), ("run.dir=''", "run.dir"),
    ("run.max_seconds=-1", "run.max_seconds"), ("service.metrics_port=70000", "service.metrics_port"),
    ("service.call_timeout_s=-1", "service.call_timeout_s"),
    ("env.num_envs=0", "env.num_envs"),
    ("env.factory=nope", "env.factory"), ("env.agent_radius=0.7", "env.agent_radius"),
    ("env.num_predators=0", "env.num_predators"), ("env.tag_shared_reward=1", "env.tag_shared_reward"),
    ("maddpg.entity_pool=max", "maddpg.entity_pool"), ("run.episodes=1.5", "run.episodes"),
])
def test_the_allowed_range_is_the_text_of_the_error(override, key):
    """A bad value's ConfigError says what the reference's "allowed" (or, for a value of the wrong type, its type's
    requirement) says, word for word."""
    section = "teams.priority" if ".priority." in key else key.split(".")[0]
    name = key.split(".")[-1]
    doc = {k.key: k for k in reference()[section].keys}[name]
    with pytest.raises(ConfigError) as err:
        load_config(None, [override])
    allowed = [*doc.allowed.split("; "), {"int": "must be an integer", "bool": "must be true or false"}.get(doc.type)]
    assert any(str(err.value).startswith(f"{key} {text}, got ") for text in allowed if text), (str(err.value), allowed)


def test_defaults_are_a_runs_defaults():
    docs = {k.key: k for k in reference()["env"].keys}
    assert docs["shared_reward"].default == "false" and docs["tag_shared_reward"].default == "false"
    assert docs["cover_radius"].default == "0.1" and docs["cover_radius"].unit == "arena units"
    maddpg = {k.key: k for k in reference()["maddpg"].keys}
    assert maddpg["networks"].default == "\"per_agent\"" and maddpg["update_every"].default == "16"


def test_one_section_is_printed_and_an_unknown_one_is_refused_in_one_line(capsys):
    assert main(["config", "replay"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("[replay]") and "[maddpg]" not in out
    entry = r"  capacity = 5000\n +meaning .+\n( .+\n)* +unit +transitions\n +type +int\n +allowed +must be >= 1\n"
    assert re.search(entry, out)
    assert main(["config", "nonsense"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == ("error: unknown section or key 'nonsense' (sections: env, task_curriculum, maddpg, replay, "
                            "curriculum, teachers, icm, run, service, teams, teams.priority; a key: SECTION.KEY, e.g. "
                            "maddpg.hidden or teams.agent.eta)\n")


@pytest.mark.parametrize(("key", "table", "shown"), [("maddpg.hidden", "[maddpg]", "  hidden = 64\n"),
                                                     ("env.num_agents", "[env]", "  num_agents = 4\n"),
                                                     ("teams.prey.eta", "[teams.<team>]", "  eta = 0.5\n"),
                                                     ("teams.agent.priority.alpha", "[teams.<team>.priority]",
                                                      "  alpha = unset\n")])
def test_one_key_is_printed_under_its_section_and_an_unknown_one_refused(capsys, key, table, shown):
    assert main(["config", key]) == 0
    out = capsys.readouterr().out
    assert out.startswith(table) and shown in out and len(re.findall(r"(?m)^  \S+ = ", out)) == 1, out
    assert main(["config", key + "x"]) == 2
    assert capsys.readouterr().err.startswith(f"error: unknown section or key {key + 'x'!r}")


def test_only_the_services_ray_keys_say_they_are_the_services():
    """Both runners schedule the same roles: a [service] key is the inline runner's too (service.updates_per_call)
    but for the Ray-only ones (cmcl.config.runners.SERVICE_ONLY), whose meaning says so."""
    from cmcl.config.runners import IN_ONE_PROCESS, SERVICE_ONLY

    docs = reference()
    service = {k.key: k for k in docs["service"].keys}
    assert {f"service.{key}" for key, doc in service.items() if "The service runner only" in doc.meaning} == \
        SERVICE_ONLY
    assert service["metrics_port"].meaning.endswith(f". The service runner only: {IN_ONE_PROCESS}")
    assert "runner only" not in service["updates_per_call"].meaning + service["checkpoint_every_s"].meaning
    assert not any("runner only" in k.meaning for name, section in docs.items() if name != "service"
                   for k in section.keys)
