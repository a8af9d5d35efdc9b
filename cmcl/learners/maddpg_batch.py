"""The per-owner minibatch a MADDPG update reads: its dict of arrays, checked and converted once to float32 tensors.

Where it sits: the learner hands :meth:`cmcl.learners.maddpg.MADDPG.update` (and ``td_abs``, ``critic_loss``) one
minibatch per agent ("batch owner", ALGORITHM.md §2/§3.6), stacked with a leading owner axis: ``obs[N, S, N, obs_dim]``,
``act[N, S, N, act_dim]``, ``rew[N, S, N]`` (or the owner's own ``[N, S]``), ``next_obs[N, S, N, obs_dim]``, optional
``done[N, S]`` or per agent ``[N, S, N]``, ``is_weights[N, S]``, ``present`` bool[N, S, N]
(cmcl.learners.agent_presence) and, with actor_batch = "uniform", the actor step's own rows under ``ACTOR_PREFIX``
(cmcl.messages). Reads the batch only; touches no network.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import torch

from cmcl.learners.agent_presence import AgentPresence
from cmcl.learners.nets import as_tensor
from cmcl.messages import ACTOR_PREFIX

__all__ = ["OwnerBatch", "actor_rows", "owner_batch"]


class OwnerBatch(NamedTuple):
    """A per-owner minibatch as tensors (unpacks as the tuple ``obs, act, rew, next_obs, done, weights, presence``)."""

    obs: torch.Tensor  # float32[N, S, N, obs_dim]
    act: torch.Tensor  # float32[N, S, N, act_dim]
    rew: torch.Tensor  # float32[N, S, N] or the owner's own [N, S]
    next_obs: torch.Tensor  # float32[N, S, N, obs_dim]
    done: torch.Tensor  # float32[N, S] or [N, S, N]; zeros when the batch has none
    weights: torch.Tensor | None  # is_weights float32[N, S] (critic only), None: unweighted
    presence: AgentPresence | None  # None: every agent of every row


def owner_batch(batch: Mapping[str, np.ndarray | torch.Tensor], num_agents: int, networks: str) -> OwnerBatch:
    """The critic's rows of a per-owner minibatch dict as tensors; ValueError on an obs that is not
    [N=num_agents, S, N, obs_dim], or on rows with absent agents for ``networks`` other than "entity"."""
    obs, act = as_tensor(batch["obs"]), as_tensor(batch["act"])
    n, s = obs.shape[0], obs.shape[1]
    if obs.dim() != 4 or n != num_agents or obs.shape[2] != num_agents:
        raise ValueError(f"obs must be [N={num_agents}, S, N, obs_dim], got {tuple(obs.shape)}")
    done = batch.get("done")
    done = torch.zeros(n, s) if done is None else as_tensor(done)
    w = batch.get("is_weights")
    presence = AgentPresence.of_batch(batch.get("present"), num_agents)
    if presence is not None and networks != "entity":
        raise ValueError(f"rows with absent agents (run.carry_replay) need entity networks, not {networks!r}")
    return OwnerBatch(obs, act, as_tensor(batch["rew"]), as_tensor(batch["next_obs"]), done,
                      None if w is None else as_tensor(w), presence)


def actor_rows(batch: Mapping[str, np.ndarray | torch.Tensor], obs: torch.Tensor, act: torch.Tensor,
               presence: AgentPresence | None, num_agents: int) -> tuple:
    """The actor step's rows (obs [N, B, N, obs_dim], act [N, B, N, act_dim], presence): the batch's "actor_obs",
    "actor_act" (and "actor_present") when it has them (actor_batch = "uniform"), else the critic's (obs, act,
    presence) as given. ValueError when their shapes do not match the critic's rows but for B."""
    if ACTOR_PREFIX + "obs" not in batch:
        return obs, act, presence
    a_obs, a_act = as_tensor(batch[ACTOR_PREFIX + "obs"]), as_tensor(batch[ACTOR_PREFIX + "act"])
    if a_obs.dim() != 4 or a_obs.shape[0] != num_agents or a_obs.shape[2:] != obs.shape[2:] \
            or a_act.shape[:2] != a_obs.shape[:2] or a_act.shape[2:] != act.shape[2:]:
        raise ValueError(f"actor_obs / actor_act must be [N={num_agents}, B, N, ·] like obs / act, got "
                         f"{tuple(a_obs.shape)} and {tuple(a_act.shape)}")
    return a_obs, a_act, AgentPresence.of_batch(batch.get(ACTOR_PREFIX + "present"), num_agents)
