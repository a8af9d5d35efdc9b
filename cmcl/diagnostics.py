"""The curriculum's own diagnostics of a sampling distribution: where the sampling mass sits among the KP branches,
how concentrated it is, and how old and how hard the rows it favours are.

Where it sits: read-only, over the per-row terms `ReplayBuffer.recompute_priorities(details=True)` returns and the
buffer's row metadata; the inline loop logs it in its progress rows (`metrics.jsonl`, key "curriculum").
Used to tell a curriculum that reweights the buffer from one that has collapsed onto a few rows or to uniform.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.replay.priority import sampling_probabilities


def ess_fraction(probs: np.ndarray) -> np.ndarray:
    """Effective sample size 1 / Σ P² of each column of probs float[M, A] (columns sum to 1), as a fraction of M:
    float[A] (1 = uniform, 1/M = all mass on one row). Clipped to at most 1: for uniform columns, Σ P² rounds
    below 1/M for about a third of the sizes M (1.0000000000000087 at M = 21), which the report schema refuses."""
    probs = np.asarray(probs, np.float64)
    return np.minimum(1.0 / np.maximum((probs ** 2).sum(0), 1e-300) / max(probs.shape[0], 1), 1.0)


def buffer_branch_shares(c_hat: np.ndarray, scored: np.ndarray, lam: float) -> dict[str, float]:
    """Share of the scored (row, agent) entries of the buffer in each branch of KP (eq. 12): rising ĉ <= λ,
    ramp λ < ĉ < 2λ, excluded ĉ >= 2λ. c_hat float[M, A], scored bool[M, A]; {} when nothing is scored."""
    c = np.asarray(c_hat)[np.asarray(scored, bool)]
    if not c.size:
        return {}
    return {"rising": float((c <= lam).mean()), "ramp": float(((c > lam) & (c < 2 * lam)).mean()),
            "excluded": float((c >= 2 * lam).mean())}


def curriculum_diagnostics(c_hat: np.ndarray, probs: np.ndarray, lam: float, age: np.ndarray) -> dict[str, list]:
    """Per agent (columns), expected under the sampling distribution P, against the buffer's uniform average:

    c_hat float[M, A] normalised difficulty, probs float[M, A] (columns sum to 1), lam the curriculum factor,
    age float[M] learner updates since each row was written. Returns lists of length A:
    share_rising / share_falling / share_excluded: P-mass with ĉ <= λ, λ < ĉ < 2λ, ĉ >= 2λ (eq. 12's branches);
    ess_fraction: effective sample size 1 / Σ P² over M (1 = uniform); difficulty_sampled / difficulty_buffer:
    E_P[ĉ] and the plain mean of ĉ; age_sampled / age_buffer: E_P[age] and the plain mean age (updates).
    """
    c_hat, probs = np.asarray(c_hat, np.float64), np.asarray(probs, np.float64)
    rising, falling = c_hat <= lam, (c_hat > lam) & (c_hat < 2 * lam)
    excluded = ~(rising | falling)
    age = np.asarray(age, np.float64)[:, None]
    out = {"share_rising": (probs * rising).sum(0), "share_falling": (probs * falling).sum(0),
           "share_excluded": (probs * excluded).sum(0),
           "ess_fraction": ess_fraction(probs),
           "difficulty_sampled": (probs * c_hat).sum(0), "difficulty_buffer": c_hat.mean(0),
           "age_sampled": (probs * age).sum(0), "age_buffer": np.broadcast_to(age.mean(), (c_hat.shape[1],))}
    return {k: [round(float(x), 4) for x in v] for k, v in out.items()}


def buffer_diagnostics(replay: Any, lam: float, alpha: float, updates: int) -> dict[str, dict]:
    """The priority statistics and the curriculum diagnostics of a buffer's ACL / CMCL agents at λ.

    Recomputes the priorities (`ReplayBuffer.recompute_priorities(lam, details=True)`); `updates` is the learner's
    update count, so a row's age is updates − the policy version that wrote it. Returns {"priority": {"agents",
    "mean", "kp_zero_fraction", "c_hat_mean", "cp_mean"} (lists over agents), "curriculum": see
    `curriculum_diagnostics`}.
    """
    details = replay.recompute_priorities(lam, details=True)
    priority = {"agents": details["agents"], "mean": details["priority"].mean(0),
                "kp_zero_fraction": (details["kp"] == 0).mean(0), "c_hat_mean": details["c_hat"].mean(0),
                "cp_mean": details["cp"].mean(0)}
    probs = sampling_probabilities(details["priority"], alpha)
    age = updates - replay.storage.policy_version[:replay.size]
    return {"priority": priority, "curriculum": curriculum_diagnostics(details["c_hat"], probs, lam, age)}
