"""Diagnostics of the sampling distributions: where the curriculum's sampling mass sits among the KP branches,
how concentrated every agent's distribution is (ESS), how much of it lands on reward-bearing rows, and how old and
how hard the rows it favours are.

Where it sits: read-only, over the per-row terms `ReplayBuffer.recompute_priorities(details=True)` returns, the
samplers' current distributions (`ReplayBuffer.sampling_distribution`) and the buffer's rows; the inline loop logs
them in its progress rows (`metrics.jsonl`, keys "sampling" for every agent and "curriculum" for ACL / CMCL
agents); the replay server can report `replay_sampling_diagnostics` (a pure function of the buffer).
Used to tell a curriculum that reweights the buffer from one that has collapsed onto a few rows or to uniform.

Reward-bearing row: a row whose reward for that agent is > 0. In sparse navigation only C2 = +4 (the agent
covers a landmark, §6.1) is positive; C1 = −1 (collision, wall) is not counted. In predator-prey it is a capture
for a predator (D1 = +5); a prey never has one.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def ess_fraction(probs: np.ndarray) -> np.ndarray:
    """Effective sample size 1 / Σ P² of each column of probs float[M, A] (columns sum to 1), as a fraction of M:
    float[A] (1 = uniform, 1/M = all mass on one row). Clipped to at most 1: for uniform columns, Σ P² rounds
    below 1/M for about a third of the sizes M (1.0000000000000087 at M = 21), which the report schema refuses."""
    probs = np.asarray(probs, np.float64)
    return np.minimum(1.0 / np.maximum((probs ** 2).sum(0), 1e-300) / max(probs.shape[0], 1), 1.0)


def buffer_branch_shares(c_hat: np.ndarray, scored: np.ndarray, lam: float) -> dict[str, float]:
    """Share of the scored (row, agent) entries of the buffer in each branch of KP (eq. 12): rising ĉ <= λ,
    falling λ < ĉ < 2λ, excluded ĉ >= 2λ. c_hat float[M, A], scored bool[M, A]; {} when nothing is scored."""
    c = np.asarray(c_hat)[np.asarray(scored, bool)]
    if not c.size:
        return {}
    return {"rising": float((c <= lam).mean()), "falling": float(((c > lam) & (c < 2 * lam)).mean()),
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


def sampling_diagnostics(probs: np.ndarray, rewards: np.ndarray) -> dict[str, list]:
    """Per agent (columns): ESS and reward-bearing rows of a sampling distribution against the buffer.

    probs float[M, A] (columns sum to 1), rewards float[M, A] (each row's reward for that agent). Returns lists of
    length A: ess_fraction (1 / Σ P² over M; 1 = uniform); reward_rows_sampled: P-mass on rows with reward > 0, the
    expected share of such rows in a sampled minibatch; reward_rows_buffer: their plain share of the buffer. A
    sampler that favours reward-bearing rows (PER, typically) has sampled > buffer; a curriculum that excludes
    the hard rows first (A1) may have sampled < buffer.
    """
    probs = np.asarray(probs, np.float64)
    bearing = np.asarray(rewards) > 0  # [M, A]
    out = {"ess_fraction": ess_fraction(probs), "reward_rows_sampled": (probs * bearing).sum(0),
           "reward_rows_buffer": bearing.mean(0) if bearing.shape[0] else np.zeros(bearing.shape[1])}
    return {k: [round(float(x), 4) for x in v] for k, v in out.items()}


def replay_sampling_diagnostics(replay: Any) -> dict[str, list]:
    """`sampling_diagnostics` of every agent of a `ReplayBuffer` as its samplers hold it now (uniform agents: ESS 1,
    sampled share = buffer share), plus "modes" (the name of each agent's sampling distribution: "uniform", "per",
    "acl" or "cmcl"). Pure: reads the buffer, changes
    nothing; {} for an empty buffer. The replay server's metrics report can call it as is."""
    size = replay.size
    if not size:
        return {}
    out = sampling_diagnostics(replay.sampling_distribution(), replay.storage.rew[:size])
    return {"modes": [s.name for s in replay.sampling], **out}


def buffer_diagnostics(replay: Any, lam: float, updates: int) -> dict[str, dict]:
    """The sampling diagnostics of every agent, and the priority statistics and curriculum diagnostics of the ACL /
    CMCL agents at λ.

    Read-only: the per-row terms come from `ReplayBuffer.recompute_priorities(lam, details=True, apply=False)` and
    the probabilities from what the samplers hold (their last recompute, permuted under the permuted control), so
    logging never changes a run (nor draws from the permuted control's generator); `updates` is the learner's
    update count, so a row's age is updates − the policy version that wrote it. Returns {"sampling": see
    `replay_sampling_diagnostics`} and, when some agent samples by the curriculum, {"priority": {"agents", "mean",
    "kp_zero_fraction", "c_hat_mean", "cp_mean"} (lists over those agents), "curriculum": see
    `curriculum_diagnostics`}.
    """
    details = replay.recompute_priorities(lam, details=True, apply=False) if replay.curriculum else None
    out: dict[str, dict] = {"sampling": replay_sampling_diagnostics(replay)}
    if details is None or not replay.size:
        return out
    priority = {"agents": details["agents"], "mean": details["priority"].mean(0),
                "kp_zero_fraction": (details["kp"] == 0).mean(0), "c_hat_mean": details["c_hat"].mean(0),
                "cp_mean": details["cp"].mean(0)}
    probs = replay.sampling_distribution()[:, details["agents"]]  # what the samplers hold: per-agent α, controls
    age = updates - replay.storage.policy_version[:replay.size]
    return {**out, "priority": priority, "curriculum": curriculum_diagnostics(details["c_hat"], probs, lam, age)}
