"""Which agents each row of a learner minibatch holds, and the means of the MADDPG losses over the present ones.

Where it sits: a buffer holding rows carried from a run with fewer agents (`run.carry_replay`,
cmcl.replay.agent_padding) hands the learner `present` bool[N, S, N] with each per-owner minibatch (owner v, row s,
agent j; the present agents of a row are always its first ones). :class:`cmcl.learners.maddpg.MADDPG` then
- gives the entity networks each row's count of present agents, so that absent agents' entity slots (their
  observation, their action, their target action) are masked out of every present agent's embedding and Q
  (cmcl.learners.entity.nets);
- takes the critic loss (eq. 5) and the actor loss (eq. 4) of owner v as the mean over the rows where v itself is
  present (`row_mean`), and their total over the owners that have such a row (`total`): an owner absent from every
  row of its minibatch adds nothing, so a minibatch of n-agent rows padded to N agents gives the losses, the
  gradients and the step of the same rows at n agents.
Without absent agents (`AgentPresence.of_batch` returns None) every mean is the unmasked one, unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["AgentPresence", "row_mean"]


@dataclass(frozen=True)
class AgentPresence:
    """count int64[N, S]: the present agents of owner v's row s; own float32[N, S]: 1 where owner v is one of them."""

    count: torch.Tensor
    own: torch.Tensor

    @staticmethod
    def of_batch(present: np.ndarray | torch.Tensor | None, num_agents: int) -> AgentPresence | None:
        """From a minibatch's present bool[N, S, N]; None when it is absent or every agent is present."""
        if present is None:
            return None
        p = torch.as_tensor(np.asarray(present)) if not isinstance(present, torch.Tensor) else present
        if p.dtype != torch.bool or p.dim() != 3 or p.shape[0] != num_agents or p.shape[2] != num_agents:
            raise ValueError(f"present must be bool [N={num_agents}, S, N], got {p.dtype} {tuple(p.shape)}")
        if bool(p.all()):
            return None
        owners = torch.arange(num_agents)
        return AgentPresence(p.sum(-1), p[owners, :, owners].to(torch.float32))

    def total(self, loss: torch.Tensor) -> torch.Tensor:
        """Mean of per-owner losses [N] over the owners with at least one row where they are present."""
        return loss.sum() / (self.own.sum(1) > 0).sum().clamp(min=1)


def row_mean(x: torch.Tensor, weights: torch.Tensor | None, presence: AgentPresence | None) -> torch.Tensor:
    """Per-owner mean of x float32[N, S] over its rows (times the IS weights [N, S] if given) -> float32[N]; with a
    presence, over the rows where the owner is present only (0 for an owner with none)."""
    if presence is None:
        return (x * weights).mean(1) if weights is not None else x.mean(1)
    own = presence.own if weights is None else presence.own * weights
    return (x * own).sum(1) / presence.own.sum(1).clamp(min=1.0)
