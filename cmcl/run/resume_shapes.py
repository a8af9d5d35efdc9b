"""What a resume may not change: the shapes a run's checkpoints hold.

`python -m cmcl resume DIR --set KEY=VALUE` resumes under the run's config.toml with the overrides. An override that
changes what the checkpoints hold (the agents, their observation and action sizes, the teams' sampling rules, the
networks' shapes, the teacher folds, the replay's capacity) cannot be restored; before, the inline runner said so in
a line naming a tensor or a replay field ("alpha in state must be a scalar or have one entry per agent (3), got 4"),
and the service ended in a traceback from its replay server's start. `check_resume_shapes` compares the shapes both
configs build, before anything starts (no Ray, no run directory change), and names the keys set.

Where it sits: the command-line layer (cmcl.run.flags.resumed_config) calls it; it builds the networks on the CPU
(torch, milliseconds) from `cmcl.system`, never a replay buffer.
"""

from __future__ import annotations

from typing import Any

from cmcl.config import Config, ConfigError
from cmcl.config.toml_io import parse_override


def checkpoint_shapes(config: Config) -> dict[str, Any]:
    """What `config`'s checkpoints hold, as {part: value}: the agent layout (agents, observation and action sizes,
    each agent's sampling rule, who needs teachers and curiosity), the replay's capacity, the teacher folds, and the
    shape of every tensor of the MADDPG learner, the teachers and the ICM."""
    from cmcl.system import build_icm, build_maddpg, build_teachers, layout_of

    layout = layout_of(config)
    shapes: dict[str, Any] = {
        "agents": layout.num_agents, "observation size": layout.obs_dim, "action size": layout.act_dim,
        "sampling rule of each agent": layout.algorithms, "agents with teachers": tuple(layout.teacher_agents.tolist()),
        "agents with curiosity": tuple(layout.icm_agents.tolist()), "replay.capacity": config.replay.capacity,
        "teachers.num_folds": config.teachers.num_folds}
    modules = {"maddpg": build_maddpg(config, layout, 0), "teachers": build_teachers(config, layout, 0),
               "icm": build_icm(config, layout, 0)}
    for name, module in modules.items():
        if module is not None:
            shapes |= {f"{name} {key}": shape for key, shape in _tensor_shapes(module.state_dict())}
    return shapes


def _tensor_shapes(state: Any, prefix: str = "") -> list[tuple[str, tuple[int, ...]]]:
    """(dotted key, shape) of every tensor in a nested state dict (optimizer states included)."""
    if hasattr(state, "shape") and hasattr(state, "dtype"):
        return [(prefix, tuple(state.shape))]
    if isinstance(state, dict):
        return [pair for key, value in state.items() for pair in _tensor_shapes(value, f"{prefix}.{key}" if prefix
                                                                                       else str(key))]
    if isinstance(state, list | tuple):
        return [pair for i, value in enumerate(state) for pair in _tensor_shapes(value, f"{prefix}.{i}")]
    return []


def check_resume_shapes(stored: Config, resumed: Config, overrides: tuple[str, ...]) -> None:
    """ConfigError naming the `overrides` (section.key=value) when the resumed config's checkpoints would differ in
    shape from the stored one's, with the first part that differs; nothing is built when no override changes a
    value."""
    if stored == resumed:
        return
    before, after = checkpoint_shapes(stored), checkpoint_shapes(resumed)
    differs = [part for part in dict.fromkeys([*before, *after]) if before.get(part) != after.get(part)]
    if differs:
        part, changed = differs[0], _shape_changers(stored, before, _changed(stored, resumed, overrides))
        raise ConfigError(f"resume --set {' --set '.join(changed)}: the run's checkpoints hold other shapes ({part}: "
                          f"{_shown(before.get(part))} in them, {_shown(after.get(part))} with these settings); a "
                          "resume keeps the settings that shape its networks and replay: drop the --set, or start a "
                          "new run (run.init_from warm-starts it from this one where the shapes allow)")


def _changed(stored: Config, resumed: Config, overrides: tuple[str, ...]) -> list[str]:
    """The overrides (section.key=value) whose key has another value in `resumed` than in `stored`."""
    before, after = stored.to_dict(), resumed.to_dict()

    def value(data: Any, key: str) -> Any:
        for part in key.split("."):
            data = data.get(part) if isinstance(data, dict) else None
        return data

    keys = {item: ".".join(parse_override(item)[0]) for item in overrides}
    return [item for item, key in keys.items() if value(before, key) != value(after, key)]


def _shape_changers(stored: Config, before: dict[str, Any], changed: list[str]) -> list[str]:
    """The overrides of `changed` that alone change the shapes `before` (`stored`'s); all of `changed` when none
    does alone (only their combination)."""
    from cmcl.config import apply_overrides, config_from_dict

    alone = [item for item in changed
             if checkpoint_shapes(config_from_dict(apply_overrides(stored.to_dict(), [item]))) != before]
    return alone or changed


def _shown(value: Any) -> str:
    return "none" if value is None else str(value)
