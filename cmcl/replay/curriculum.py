"""Curriculum-factor schedule λ_t (ALGORITHM.md §3.7, A10).

Where it sits in the flow: whoever counts accepted environment steps (the inline loop, or the replay server
in the service) owns one `CurriculumSchedule`, calls `advance(n)` as steps arrive and passes `lam` to
`ReplayBuffer.recompute_priorities`. λ does not move during warm-up.

    linear:          λ_t = min(λ_max, λ_0 + Δλ · t_learn)
    multiplicative:  λ_t = min(λ_max, λ_0 · (1 + κ)^t_learn)       (CHER-style alternative)

with t_learn = max(0, env_steps − warmup_steps), all counted in environment steps (transitions) on the budget's
clock: an episode counts `env.episode_length` steps however long it was, since the run's budget (and the default
stride's ramp) is run.episodes × episode_length. The step counters add, when an episode ends early, the steps it did
not take (`unplayed_steps`); otherwise λ lags on environments with shorter episodes (mpe2 simple_push, 25-step
episodes under a 30-step episode_length, 200 episodes: the default stride reached λ_max at episode 121 instead of
101, a stride set to reach it at the budget's end stopped at 0.84). Fixed-length episodes add 0.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

KINDS = ("linear", "multiplicative")


def unplayed_steps(lengths: np.ndarray, episode_length: int) -> int:
    """Σ (episode_length − length) over ended episodes of `lengths` int[M]: the budgeted steps they did not take,
    which the schedule's clock counts when they end (0 for episodes of episode_length steps)."""
    return int(np.maximum(0, int(episode_length) - np.asarray(lengths, np.int64)).sum())


def ramp_steps(total_env_steps: int) -> int:
    """Post-warm-up env steps over which the default schedules take λ from λ_0 to λ_max: half of training."""
    if int(total_env_steps) != total_env_steps or total_env_steps < 1:
        raise ValueError(f"total_env_steps must be an integer >= 1, got {total_env_steps!r}")
    return max(1, int(total_env_steps) // 2)


def default_stride(total_env_steps: int, lam0: float = 0.1, lam_max: float = 1.0) -> float:
    """Δλ per post-warm-up env step of the linear schedule reaching λ_max at half of training:
    (λ_max − λ_0) / ⌊T/2⌋; 0.9 / 300 000 = 3e-6 for T = 600 000 (20 000 episodes × 30 steps)."""
    return (lam_max - lam0) / ramp_steps(total_env_steps)


def default_growth(total_env_steps: int, lam0: float = 0.1, lam_max: float = 1.0) -> float:
    """κ of the multiplicative schedule reaching λ_max at half of training: (λ_max/λ_0)^(1/⌊T/2⌋) − 1."""
    return (lam_max / lam0) ** (1.0 / ramp_steps(total_env_steps)) - 1.0


class CurriculumSchedule:
    """λ as a function of environment steps; stateful counter plus a pure `value(t_learn)`. Its settings come
    from the [curriculum] section, checked when the config is loaded (cmcl.config.learning), not again here.

    Args:
        lam0: initial λ_0 (0 < λ_0 <= λ_max).
        lam_max: cap λ_max (<= 1, the largest λ for which KP is defined).
        stride: Δλ per post-warm-up env step (linear kind), >= 0.
        warmup_steps: env steps (on the same clock) before λ starts to move (§5: 3840 = batch 128 × 30-step
            episodes).
        kind: "linear" (default) or "multiplicative".
        growth: κ per post-warm-up env step (multiplicative kind), >= 0. Default reaches 1.0 from 0.1 after
            300 000 steps, like the default linear stride.
    """

    def __init__(
        self,
        lam0: float = 0.1,
        lam_max: float = 1.0,
        stride: float = 3e-6,
        warmup_steps: int = 3840,
        kind: str = "linear",
        growth: float | None = None,
    ) -> None:
        if growth is None:
            growth = default_growth(600_000, lam0=0.1, lam_max=1.0)
        self.lam0 = float(lam0)
        self.lam_max = float(lam_max)
        self.stride = float(stride)
        self.warmup_steps = int(warmup_steps)
        self.kind = kind
        self.growth = float(growth)
        self.env_steps = 0

    def value(self, t_learn: int | float) -> float:
        """λ after `t_learn` post-warm-up env steps (negative counts as 0)."""
        t = max(0.0, float(t_learn))
        if self.kind == "linear":
            return min(self.lam_max, self.lam0 + self.stride * t)
        log_ratio = t * math.log1p(self.growth)  # log space: no overflow
        if log_ratio >= math.log(self.lam_max / self.lam0):
            return self.lam_max
        return min(self.lam_max, self.lam0 * math.exp(log_ratio))

    @property
    def t_learn(self) -> int:
        """Environment steps counted after warm-up."""
        return max(0, self.env_steps - self.warmup_steps)

    @property
    def lam(self) -> float:
        """Current λ."""
        return self.value(self.t_learn)

    def advance(self, n_env_steps: int = 1) -> float:
        """Count `n_env_steps` more environment steps (integer >= 0); returns the new λ."""
        self.env_steps += int(n_env_steps)
        return self.lam

    def state_dict(self) -> dict:
        """Plain scalars: env_steps (the only state), plus lam and the settings for inspection."""
        return {
            "env_steps": int(self.env_steps),
            "lam": float(self.lam),
            "lam0": self.lam0,
            "lam_max": self.lam_max,
            "stride": self.stride,
            "warmup_steps": self.warmup_steps,
            "kind": self.kind,
            "growth": self.growth,
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore the step counter. Settings come from the constructor; a mismatch raises ValueError."""
        steps = state.get("env_steps")
        if not isinstance(steps, numbers.Integral) or isinstance(steps, bool) or steps < 0:
            raise ValueError(f"env_steps must be an integer >= 0, got {steps!r}")
        for key in ("lam0", "lam_max", "stride", "warmup_steps", "kind", "growth"):
            if key in state and state[key] != getattr(self, key):
                raise ValueError(f"{key} in state ({state[key]!r}) differs from this schedule ({getattr(self, key)!r})")
        self.env_steps = int(steps)
