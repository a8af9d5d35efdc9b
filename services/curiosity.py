"""ICM actor: trains every curiosity-using agent's ICM on uniform replay batches and scores buffer rows with ρ.

Where it sits: replay -> ICM -> curiosity scores back to replay (ALGORITHM.md §3.4, distributed as in §3.9).
It needs no policy weights: the ICM models (o, a, o') only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.system import agent_layout, build_icm, make_batched_env
from services.common import actor_setup, load_state, new_incarnation, save_state


def _own(rows: dict[str, np.ndarray], agents: np.ndarray, key: str) -> np.ndarray:
    """Agent-major slices of joint rows: rows[key] [..., M, N, d] -> [A, ..., M, d] for the given agents."""
    return np.ascontiguousarray(np.moveaxis(rows[key][..., agents, :], -2, 0))


class CuriosityWorker:
    """Per-agent ICMs of the curiosity agents, as one stacked module."""

    def __init__(self, config: Any, seed: int, checkpoint_path: str | None = None):
        self.config = cfg = actor_setup(config)
        self.incarnation, self.checkpoint_path = new_incarnation(), checkpoint_path
        self.layout = agent_layout(cfg, make_batched_env(cfg, num_envs=1))
        self.icm = build_icm(cfg, self.layout, seed)
        if self.icm is None:
            raise ValueError("no team uses curiosity: the ICM actor is not needed for this config")
        self.loss = 0.0
        state = load_state(checkpoint_path)
        self.resumed = state is not None
        if state is not None:
            self.icm.load_state_dict(state["icm"])

    def step(self, work: dict[str, Any] | None) -> tuple[dict[str, Any] | None, dict[str, Any]]:
        """Fit on work["fit"] ([steps, S, N, ·] rows), then return ρ float32[M, A_c] of work["score"] rows."""
        if work is None:
            return None, self.report()
        a, fit = self.layout.icm_agents, work["fit"]
        obs, act, nxt = (_own(fit, a, k) for k in ("obs", "act", "next_obs"))  # [A_c, steps, S, ·]
        for i in range(obs.shape[1]):
            out = self.icm.train_step(obs[:, i], act[:, i], nxt[:, i])
            self.loss = float(np.mean(out["inverse_loss"]) + np.mean(out["forward_loss"]))
        score = work["score"]
        rho = self.icm.curiosity(*(_own(score, a, k) for k in ("obs", "act", "next_obs"))).T.copy()  # [M, A_c]
        return {"slots": score["slots"], "generations": score["generations"], "rho": rho,
                "updates": work["updates"], "loss": self.loss}, self.report()

    def report(self) -> dict[str, Any]:
        """Metrics report (steps / scores are counted by the replay server)."""
        return {"source": "icm", "role": "icm", "incarnation": self.incarnation, "resumed": self.resumed}

    def save(self) -> str | None:
        """Write the ICM checkpoint atomically."""
        return save_state(self.checkpoint_path, {"icm": self.icm.state_dict()})
