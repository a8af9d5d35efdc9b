"""Numpy inference of the stacked tanh actors: what rollout workers run, without loading torch.

Where it sits: rollout workers load the learner's published online actor (cmcl.learners.weights, "actor" part) into a
`NumpyPolicy` and act with it. It computes exactly MADDPG.act for continuous actions (tanh MLP, Gaussian
noise, clip to [-1, 1]); a parity test ties the two. Keeping torch out of rollout workers (and the replay
server) saves ~190 MB of private memory per process.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


class NumpyPolicy:
    """All agents' actors as stacked numpy weights: layers.k.weight float32[N, in, out], layers.k.bias [N, out]."""

    def __init__(self, weights: Mapping[str, np.ndarray], act_mask: np.ndarray | None = None):
        """act_mask: float32[N, act_dim] multiplied into every action (0 on padded entries), as MADDPG's."""
        self.act_mask = None if act_mask is None else np.asarray(act_mask, np.float32)
        count = len([k for k in weights if k.endswith(".weight")])
        if count < 1 or any(f"layers.{i}.weight" not in weights or f"layers.{i}.bias" not in weights
                            for i in range(count)):
            raise ValueError(f"actor weights must hold layers.0..{count - 1}.weight/.bias, got {sorted(weights)}")
        self.weights = [np.ascontiguousarray(weights[f"layers.{i}.weight"], dtype=np.float32) for i in range(count)]
        self.biases = [np.ascontiguousarray(weights[f"layers.{i}.bias"], dtype=np.float32)[:, None, :]
                       for i in range(count)]
        for w in [*self.weights, *self.biases]:
            if not np.isfinite(w).all():
                raise ValueError("actor weights must be finite")

    def act(self, obs: np.ndarray, noise_std: float = 0.1, rng: np.random.Generator | None = None) -> np.ndarray:
        """obs float32[B, N, obs_dim] -> actions float32[B, N, act_dim] = clip(tanh(MLP(o)) + N(0, σ²), -1, 1)."""
        x = np.ascontiguousarray(np.asarray(obs, dtype=np.float32).transpose(1, 0, 2))  # [N, B, obs_dim]
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = np.matmul(x, w)
            x += b
            if i < last:
                np.maximum(x, 0.0, out=x)
        np.tanh(x, out=x)
        out = x.transpose(1, 0, 2)  # [B, N, act_dim]
        if noise_std > 0:
            rng = rng if rng is not None else np.random.default_rng()
            out = out + rng.normal(0.0, noise_std, size=out.shape).astype(np.float32)
        out = np.clip(out, -1.0, 1.0).astype(np.float32, copy=False)
        return out if self.act_mask is None else out * self.act_mask
