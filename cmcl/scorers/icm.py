"""Intrinsic curiosity module for vector observations, one per agent, stacked (ALGORITHM.md §3.4, A5/A6).

Where it sits in the flow: once per learner update (service: the ICM actor, at the configured ratio) the ICM takes
one Adam step on S transitions drawn UNIFORMLY from the buffer (:meth:`ICM.train_step`); at insertion and at every
rescoring it returns the curiosity rho_{v,j} = 1/2 ||F_v(phi_v(o), a) - phi_v(o')||^2 of buffer rows
(:meth:`ICM.curiosity`), which ``priority.py`` std-normalises and feeds to CP. No gradient flows between the ICM
and the MADDPG actors/critics: separate modules and a separate optimiser.

Members are agents (the A agents that use CMCL): phi_v: o -> 64 -> feature_dim, g_v: [phi(o), phi(o')] -> 64 ->
act_dim (inverse model), F_v: [phi(o), a] -> 64 -> feature_dim (forward model).
With ``networks="entity"`` one network of each kind serves every agent: φ is the entity encoder
(cmcl.learners.entity.nets.EntityFeatures) and g, F one MLP each, so the ICM's size depends on neither N nor A.
Inputs are per-agent slices ``obs[A, M, obs_dim]`` (from joint rows: ``obs[:, agents].transpose(0, 1)``).
``icm_scope="joint"`` (A5 option) needs no extra code: use ``ICM(num_agents=1, obs_dim=N*od, act_dim=N*ad)`` on
flattened joint rows ``[1, M, N*od]`` and share the resulting rho across the team.
Public boundary: numpy or torch in (float32), numpy out.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from cmcl.envs.entities import EntityLayout
from cmcl.learners.entity.nets import EntityFeatures
from cmcl.learners.nets import StackedMLP, adam_step_, as_tensor, clip_grad_norm_per_member_, drop_grads_, make_adam
from cmcl.learners.state_check import require_same_shapes

__all__ = ["ICM"]

ArrayLike = np.ndarray | torch.Tensor


class ICM:
    """Per-agent ICM (encoder phi, inverse g, forward F) as stacked modules, trained on (1-beta) L_I + beta L_F.

    Args:
        num_agents: A.  obs_dim, act_dim: per-agent widths.  feature_dim: width of phi (32).  hidden: 64.
        beta_forward: beta_F, weight of the forward loss (0.2).  lr: Adam rate (1e-3).
        discrete: inverse loss = cross-entropy against argmax(a) instead of ||tanh(g) - a||^2.
        grad_clip: optional per-agent gradient-norm clip (None = off, as specified).
        chunk_size: rows per forward pass in :meth:`curiosity`.  seed: initial weights.
        networks: "per_agent" (one φ, g, F per agent) or "entity" (module docstring; needs entity_layout and
            agents, the agent index of each of the A rows; entity_pool: the encoder's pooling; entity_nearest:
            k > 0, φ reads only the k nearest entities of each kind, as the learner's actor does; 0: every entity;
            entity_holder: φ reads each entity row with its holder margin, as the learner's actor does, by
            entity_holder_rule, maddpg.holder_rule).
    """

    def __init__(
        self,
        num_agents: int,
        obs_dim: int,
        act_dim: int,
        feature_dim: int = 32,
        hidden: int = 64,
        beta_forward: float = 0.2,
        lr: float = 1e-3,
        discrete: bool = False,
        grad_clip: float | None = None,
        chunk_size: int = 4096,
        seed: int = 0,
        networks: str = "per_agent",
        agents: Sequence[int] | np.ndarray | None = None,
        entity_layout: EntityLayout | None = None,
        entity_pool: str = "attention",
        entity_nearest: int = 0,
        entity_holder: bool = False,
        entity_holder_rule: str = "nearest",
    ):
        self.num_agents, self.obs_dim, self.act_dim = int(num_agents), int(obs_dim), int(act_dim)
        self.feature_dim, self.beta = int(feature_dim), float(beta_forward)
        self.discrete, self.grad_clip, self.chunk_size = bool(discrete), grad_clip, int(chunk_size)
        gen = torch.Generator().manual_seed(int(seed))
        a, self.networks = self.num_agents, networks
        if networks == "entity":
            if entity_layout is None or agents is None or len(agents) != a:
                raise ValueError(f"an entity ICM needs the entity layout and the index of each of its {a} agents")
            self.phi: torch.nn.Module = EntityFeatures(entity_layout, list(agents), hidden, feature_dim, gen,
                                                          entity_pool, entity_nearest, entity_holder,
                                                          entity_holder_rule)
            a = 1  # one inverse and one forward model, broadcast over the agents
        elif networks == "per_agent":
            self.phi = StackedMLP(a, obs_dim, (hidden,), feature_dim, generator=gen)
        else:
            raise ValueError(f"networks must be 'per_agent' or 'entity', got {networks!r}")
        self.inverse = StackedMLP(a, 2 * feature_dim, (hidden,), act_dim, generator=gen)
        self.forward_model = StackedMLP(a, feature_dim + act_dim, (hidden,), feature_dim, generator=gen)
        self.opt = make_adam(self.parameters(), lr)
        self.steps = 0

    def parameters(self) -> list[torch.nn.Parameter]:
        """All ICM parameters (encoder, inverse, forward), each with the agent axis first."""
        return [*self.phi.parameters(), *self.inverse.parameters(), *self.forward_model.parameters()]

    def _check(self, obs: torch.Tensor, act: torch.Tensor, next_obs: torch.Tensor) -> None:
        """Validate [A, M, obs_dim] / [A, M, act_dim] / [A, M, obs_dim] inputs."""
        a, m = obs.shape[0], obs.shape[1]
        if (
            obs.shape != (self.num_agents, m, self.obs_dim)
            or next_obs.shape != obs.shape
            or act.shape != (a, m, self.act_dim)
        ):
            raise ValueError(
                f"expected obs/next_obs [A={self.num_agents}, M, {self.obs_dim}] and act [A, M, {self.act_dim}], "
                f"got {tuple(obs.shape)}, {tuple(act.shape)}, {tuple(next_obs.shape)}"
            )

    def _losses(self, obs, act, next_obs) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-agent inverse loss L_I (eqs. 13–14) and forward loss L_F (eqs. 15–16), each float32[A] (batch means);
        gradients flow into phi."""
        f, f_next = self.phi(torch.cat([obs, next_obs], dim=1)).chunk(2, dim=1)  # [A, S, feat] each, one pass
        g = self.inverse(torch.cat([f, f_next], dim=-1))  # [A, S, act_dim]
        if self.discrete:
            target = act.argmax(-1)  # [A, S]
            inv = F.cross_entropy(g.flatten(0, 1), target.flatten(), reduction="none").view(target.shape).mean(1)
        else:
            inv = (torch.tanh(g) - act).pow(2).sum(-1).mean(1)
        pred = self.forward_model(torch.cat([f, act], dim=-1))  # [A, S, feat]
        fwd = 0.5 * (pred - f_next).pow(2).sum(-1).mean(1)
        return inv, fwd

    def train_step(self, obs: ArrayLike, act: ArrayLike, next_obs: ArrayLike) -> dict[str, np.ndarray | float]:
        """One Adam step for every agent's ICM on (1 − β_F)·L_I + β_F·L_F (eq. 17).

        obs float32[A, S, obs_dim], act float32[A, S, act_dim], next_obs float32[A, S, obs_dim]
        -> {"inverse_loss": float32[A], "forward_loss": float32[A], "total": float (sum over agents of
        (1-beta) L_I + beta L_F)}, all pre-step.
        """
        o, a, o2 = as_tensor(obs), as_tensor(act), as_tensor(next_obs)
        self._check(o, a, o2)
        inv, fwd = self._losses(o, a, o2)
        total = ((1.0 - self.beta) * inv + self.beta * fwd).sum()
        params = self.parameters()
        drop_grads_(params)
        total.backward()
        if self.grad_clip is not None:
            clip_grad_norm_per_member_(params, self.grad_clip)
        adam_step_(self.opt)
        self.steps += 1
        inv_np, fwd_np = inv.detach().numpy(), fwd.detach().numpy()
        return {"inverse_loss": inv_np, "forward_loss": fwd_np, "total": float(total.detach())}

    @torch.no_grad()
    def losses(self, obs: ArrayLike, act: ArrayLike, next_obs: ArrayLike) -> dict[str, np.ndarray]:
        """Evaluate L_I and L_F (float32[A] each) without a step."""
        o, a, o2 = as_tensor(obs), as_tensor(act), as_tensor(next_obs)
        self._check(o, a, o2)
        inv, fwd = self._losses(o, a, o2)
        return {"inverse_loss": inv.numpy(), "forward_loss": fwd.numpy()}

    @torch.no_grad()
    def curiosity(self, obs: ArrayLike, act: ArrayLike, next_obs: ArrayLike) -> np.ndarray:
        """rho = 1/2 ||F(phi(o), a) - phi(o')||^2 (eq. 18, no reward scale): [A, M, *] inputs -> float32[A, M] >= 0."""
        o, a, o2 = as_tensor(obs), as_tensor(act), as_tensor(next_obs)
        self._check(o, a, o2)
        out = []
        for s in range(0, o.shape[1], self.chunk_size):
            sl = slice(s, s + self.chunk_size)
            f = self.phi(o[:, sl])
            pred = self.forward_model(torch.cat([f, a[:, sl]], dim=-1))
            out.append(0.5 * (pred - self.phi(o2[:, sl])).pow(2).sum(-1))
        return (torch.cat(out, dim=1) if out else torch.zeros(self.num_agents, 0)).numpy()

    def state_dict(self) -> dict:
        """{"phi", "inverse", "forward": stacked module state dicts ([A, in, out]/[A, out]), "opt", "steps"}."""
        return {
            "phi": self.phi.state_dict(),
            "inverse": self.inverse.state_dict(),
            "forward": self.forward_model.state_dict(),
            "opt": self.opt.state_dict(),
            "steps": int(self.steps),
        }

    def load_state_dict(self, state: Mapping) -> None:
        """Restore :meth:`state_dict` output (same architecture: checked first, by name)."""
        require_same_shapes("checkpoint icm", {"phi": self.phi, "inverse": self.inverse,
                                               "forward": self.forward_model}, state,
                            "icm.networks, icm settings or agents")
        self.phi.load_state_dict(state["phi"])
        self.inverse.load_state_dict(state["inverse"])
        self.forward_model.load_state_dict(state["forward"])
        self.opt.load_state_dict(state["opt"])
        self.steps = int(state["steps"])
