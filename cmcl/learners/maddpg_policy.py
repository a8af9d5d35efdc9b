"""What a MADDPG learner's actors output: exploration actions for the rollouts, and the actions (with their raw
outputs) that the TD targets and the actor step read.

A mixin of :class:`cmcl.learners.maddpg.MADDPG`; it reads the attributes that class builds: ``actor`` (the stacked
or entity actor), ``num_agents``, ``obs_dim``, ``act_dim``, ``discrete``, ``temperature`` (Gumbel-softmax),
``act_mask`` (float32[N, 1, act_dim] or None) and ``noise_gen`` (torch.Generator).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cmcl.learners.nets import as_tensor

__all__ = ["MADDPGPolicy"]

ArrayLike = np.ndarray | torch.Tensor


class MADDPGPolicy:
    """The actors' actions of the stacked MADDPG learner (continuous tanh, or Gumbel-softmax when discrete)."""

    actor: nn.Module
    num_agents: int
    obs_dim: int
    act_dim: int
    discrete: bool
    temperature: float
    act_mask: torch.Tensor | None
    noise_gen: torch.Generator

    def _policy(self, net: nn.Module, obs: torch.Tensor, sample: bool, count: torch.Tensor | None = None,
                out: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """obs [N, B, obs_dim] (count: the present agents of each row, int64[N, B], entity networks only)
        -> (actions [N, B, act_dim], raw outputs [N, B, act_dim]).

        Continuous: the tanh output is the action. Discrete: Gumbel-softmax sample of the logits (``sample``),
        else their softmax; padded entries (act_mask 0) get probability 0 (and raw output 0). `out`: net's output
        on obs float32[N, B, act_dim] when the caller already has it (the actor step's assignment loss), else None.
        """
        if out is None:
            out = net(obs) if count is None else net(obs, count=count)
        if self.act_mask is not None:
            out = out * self.act_mask
        if not self.discrete:
            return out, out
        raw, out = out, self._padded_logits(out, self.act_mask)
        if sample:
            u = torch.rand(out.shape, generator=self.noise_gen).clamp_(1e-10, 1.0 - 1e-7)
            return F.softmax((out - torch.log(-torch.log(u))) / self.temperature, dim=-1), raw
        return F.softmax(out, dim=-1), raw

    @staticmethod
    def _padded_logits(logits: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        """Logits with −inf on the padded entries (mask 0, broadcast against logits): a softmax gives them 0."""
        return logits if mask is None else logits.masked_fill(mask == 0, float("-inf"))

    def _joint_actions(self, net: nn.Module, obs: torch.Tensor, sample: bool,
                       count: torch.Tensor | None = None) -> torch.Tensor:
        """Every agent's action from its own obs: obs [..., N, obs_dim] (count int64[...]) -> act [..., N, act_dim]."""
        lead = obs.shape[:-2]
        x = obs.reshape(-1, self.num_agents, self.obs_dim).transpose(0, 1)  # [N, B, obs_dim]
        rows = None if count is None else count.reshape(1, -1).expand(self.num_agents, -1)  # [N, B]
        a, _ = self._policy(net, x, sample, rows)
        return a.transpose(0, 1).reshape(*lead, self.num_agents, self.act_dim)

    @torch.no_grad()
    def act(self, obs: ArrayLike, noise_std: float = 0.1, rng: np.random.Generator | None = None) -> np.ndarray:
        """Exploration actions: obs float32[B, N, obs_dim] -> float32[B, N, act_dim].

        Continuous: clip(pi_v(o_v) + N(0, noise_std^2), -1, 1). Discrete: a Gumbel-softmax sample when
        noise_std > 0, the softmax otherwise. Noise comes from ``rng`` (numpy) if given, else the internal
        torch generator.
        """
        o = as_tensor(obs)
        x = o.transpose(0, 1)  # [N, B, obs_dim]
        out = self.actor(x).transpose(0, 1)  # [B, N, act_dim]
        if self.discrete:
            out = self._padded_logits(out, None if self.act_mask is None else self.act_mask.transpose(0, 1))
            if noise_std > 0:
                g = (
                    torch.from_numpy(rng.gumbel(size=out.shape).astype(np.float32))
                    if rng is not None
                    else -torch.log(-torch.log(torch.rand(out.shape, generator=self.noise_gen).clamp_(1e-10, 1 - 1e-7)))
                )
                out = (out + g) / self.temperature
            return F.softmax(out, dim=-1).numpy()
        if noise_std > 0:
            noise = (
                torch.from_numpy(rng.normal(0.0, noise_std, size=out.shape).astype(np.float32))
                if rng is not None
                else torch.randn(out.shape, generator=self.noise_gen) * noise_std
            )
            out = out + noise
        out = out.clamp_(-1.0, 1.0)
        if self.act_mask is not None:
            out = out * self.act_mask.transpose(0, 1)
        return out.numpy()
