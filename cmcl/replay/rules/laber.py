"""LaBER, large batch experience replay (Lahire et al., ICML 2022; issue 36, rule c): priorities computed fresh.

PER samples by a |δ| computed when a row was last sampled, minutes and thousands of updates ago. LaBER draws a
uniform candidate batch of m·B rows, scores every candidate with the current critic (|δ| of this update's targets)
and picks the B rows of the update from the candidates with probability ∝ |δ| (+ ε), correcting with
LaBER-mean's weights w_j = mean(p) / p_j on the critic loss. So no row is sampled by a stale score.

Here: the buffer's side is uniform (`LargeBatchSampling`; the registry's spec says `candidates` = m, and the
runners then draw m·B rows and one uniform number per picked row, `LearnerBatch.select_u`, from the same sampler
streams in both runners); the learner's side is `select_candidates`, called by
`cmcl.learners.network_steps.choose_minibatch` after one no-grad critic pass over the candidates.
"""

from __future__ import annotations

import numpy as np

from cmcl.replay.sampling import UniformSampling

CANDIDATES = 4  # m: candidates per picked row (LaBER's m = 4 in most of its experiments)


class LargeBatchSampling(UniformSampling):
    """The candidate batch: uniform over the buffer (the learner picks among the candidates)."""

    name = "laber"


def select_candidates(priority: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pick B of M candidates per agent ∝ priority by inverse CDF.

    priority float[N, M] (> 0, finite), u float[N, B] in [0, 1) -> (idx int64[N, B] into the candidates,
    weights float32[N, B] = mean(priority) / priority[idx], LaBER-mean's importance weights)."""
    p = np.asarray(priority, dtype=np.float64)
    if p.ndim != 2 or not np.all(np.isfinite(p)) or (p <= 0).any():
        raise ValueError(f"candidate priorities must be finite, > 0 and [N, M], got shape {p.shape}")
    cdf = np.cumsum(p, axis=1)
    cdf /= cdf[:, -1:]
    idx = np.minimum((cdf[:, None, :] <= np.asarray(u)[:, :, None]).sum(-1), p.shape[1] - 1)  # first cdf > u
    chosen = np.take_along_axis(p, idx, axis=1)
    return idx.astype(np.int64), (p.mean(1, keepdims=True) / chosen).astype(np.float32)
