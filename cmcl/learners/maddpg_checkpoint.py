"""What of a MADDPG learner is saved and shipped: its online actor's weights for rollout workers, and its whole
state (networks, targets, optimisers, noise generator, update counter) for checkpoints (DESIGN.md, recovery).

A mixin of :class:`cmcl.learners.maddpg.MADDPG`; it reads the attributes that class builds: ``actor``, ``critic``,
``target_actor``, ``target_critic`` (stacked modules), ``actor_opt``, ``critic_opt`` (Adam), ``noise_gen``
(torch.Generator) and ``updates`` (int).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from cmcl.learners.state_check import (
    require_same_holder,
    require_same_holder_rule,
    require_same_nearest,
    require_same_shapes,
)
from cmcl.learners.weights import load_published

__all__ = ["MADDPGCheckpoint"]


class MADDPGCheckpoint:
    """Weights out and in, state out and in, for the stacked MADDPG learner."""

    actor: torch.nn.Module
    critic: torch.nn.Module
    target_actor: torch.nn.Module
    target_critic: torch.nn.Module
    actor_opt: torch.optim.Optimizer
    critic_opt: torch.optim.Optimizer
    noise_gen: torch.Generator
    updates: int
    entity_nearest: int
    entity_holder: bool
    holder_rule: str

    def actor_weights(self) -> dict[str, np.ndarray]:
        """Online actor parameters as numpy copies, e.g. {"layers.0.weight": float32[N, obs_dim, 64], ...}."""
        return {k: v.detach().numpy().copy() for k, v in self.actor.state_dict().items()}

    def load_actor_weights(self, weights: Mapping[str, np.ndarray | torch.Tensor]) -> None:
        """Load :meth:`actor_weights` output into the ONLINE actor (rollout workers); targets untouched. Keys, shapes
        and finiteness are checked first (ValueError), as for every published part (cmcl.learners.weights)."""
        load_published(self, {"actor": weights}, ("actor",))

    def state_dict(self) -> dict:
        """Nets, targets, optimisers, noise generator state and update counter (torch.load(weights_only=True) safe).

        Layout: {"actor", "critic", "target_actor", "target_critic": module state dicts with stacked
        tensors [N, in, out] / [N, out]; "actor_opt", "critic_opt": Adam state dicts; "noise_gen": uint8 tensor;
        "updates": int; "entity_nearest": int, the k of maddpg.entity_nearest (the weights do not show it);
        "entity_holder": bool, maddpg.entity_holder; "holder_rule": str, maddpg.holder_rule}.
        """
        return {
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "target_actor": self.target_actor.state_dict(),
            "target_critic": self.target_critic.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "noise_gen": self.noise_gen.get_state(),
            "updates": int(self.updates),
            "entity_nearest": int(self.entity_nearest),
            "entity_holder": bool(self.entity_holder),
            "holder_rule": str(self.holder_rule),
        }

    def load_state_dict(self, state: Mapping) -> None:
        """Restore everything saved by :meth:`state_dict` (same architecture required: checked first, by name)."""
        parts = ("actor", "critic", "target_actor", "target_critic")
        require_same_holder("checkpoint maddpg", self.entity_holder, state)
        require_same_shapes("checkpoint maddpg", {name: getattr(self, name) for name in parts}, state,
                            "maddpg.networks, maddpg.hidden, agents or observation sizes")
        require_same_nearest("checkpoint maddpg", self.entity_nearest, state)
        require_same_holder_rule("checkpoint maddpg", self.holder_rule, state)
        for name in parts:
            getattr(self, name).load_state_dict(state[name])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.noise_gen.set_state(state["noise_gen"])
        self.updates = int(state["updates"])
