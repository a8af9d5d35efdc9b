"""Checks that a saved state fits a model before any of it is loaded, so that a checkpoint written under other
network settings fails with an error that names the part, the tensor, both shapes and the settings behind them
(not torch's raw size-mismatch message, and not after some parts were already replaced)."""

from __future__ import annotations

from collections.abc import Mapping

from torch import nn

from cmcl.replay.snapshot import OlderRunError, older_run


def require_same_shapes(owner: str, modules: Mapping[str, nn.Module], state: Mapping, settings: str) -> None:
    """Raise ValueError unless state[name] has exactly the tensor keys and shapes of modules[name] for every name.

    owner: what is loaded ("checkpoint maddpg"); settings: the config fields that set these shapes, for the
    message. Leaves every module untouched."""
    for name, module in modules.items():
        if name not in state:
            raise ValueError(f"{owner}: no {name!r} part; it holds {sorted(state)}")
        own, given = module.state_dict(), state[name]
        if set(own) != set(given):
            raise ValueError(f"{owner}.{name}: tensors {sorted(given)} differ from this config's {sorted(own)} "
                             f"(set by {settings})")
        for key, tensor in own.items():
            saved = tuple(given[key].shape)
            if saved != tuple(tensor.shape):
                raise ValueError(f"{owner}.{name}.{key} has shape {saved}, this config builds {tuple(tensor.shape)}"
                                 f": it was saved under other {settings}")


def _saved(owner: str, state: Mapping, key: str):
    """state[key]; OlderRunError (one line) for a state written before the key was kept."""
    if key not in state:
        raise OlderRunError(older_run(f"{owner} without {key!r}"))
    return state[key]


def require_same_nearest(owner: str, nearest: int, state: Mapping) -> None:
    """Raise ValueError unless the saved MADDPG state was trained with the same maddpg.entity_nearest as this model
    (`nearest`): the weights fit either way, but they were learned reading other entities."""
    saved = int(_saved(owner, state, "entity_nearest"))
    if saved != int(nearest):
        raise ValueError(f"{owner} was trained with maddpg.entity_nearest = {saved} and this config has {int(nearest)}"
                         f": the same weights would read other entities; set maddpg.entity_nearest = {saved}")


def require_same_holder(owner: str, holder: bool, state: Mapping) -> None:
    """Raise ValueError unless the saved MADDPG state was trained with the same maddpg.entity_holder as this model
    (`holder`): the entity layers take one more input with it, so the weights do not fit (checked before the shapes,
    so that the message names the setting)."""
    saved = bool(_saved(owner, state, "entity_holder"))
    if saved != bool(holder):
        toml = {True: "true", False: "false"}
        raise ValueError(f"{owner} was trained with maddpg.entity_holder = {toml[saved]} and this config has "
                         f"{toml[bool(holder)]}: its entity layers read {'one more' if saved else 'one fewer'} "
                         f"input; set maddpg.entity_holder = {toml[saved]}")


def require_same_holder_rule(owner: str, rule: str, state: Mapping) -> None:
    """Raise ValueError unless the saved MADDPG state was trained with the same maddpg.holder_rule as this model
    (`rule`): the weights fit either way, but they learned to read the margin by the saved rule."""
    saved = str(_saved(owner, state, "holder_rule"))
    if saved != rule:
        raise ValueError(f"{owner} was trained with maddpg.holder_rule = {saved!r} and this config has {rule!r}: the "
                         f"same weights would read another margin; set maddpg.holder_rule = {saved!r}")
