"""laber: LaBER, large batch experience replay (Lahire et al., ICML 2022), priorities computed fresh.

PER samples by a |δ| computed when a row was last sampled, minutes and thousands of updates ago. LaBER draws a
uniform candidate batch of m·B rows, scores every candidate with the current critic (|δ| of this update's targets)
and picks the B rows of the update from the candidates with probability ∝ |δ| (+ ε), correcting with
LaBER-mean's weights w_j = mean(p) / p_j on the critic loss. So no row is sampled by a stale score.

Here: the buffer's side is uniform (`LargeBatchSampling`; the rule's `candidates` is m, `teams.<team>.candidates`,
and the runners then draw m·B rows and one uniform number per picked row, `LearnerBatch.select_u`, from the same sampler
streams in both runners); the learner's side is the rule's `pick`, `select_candidates`, called by
`cmcl.learners.network_steps.choose_minibatch` after one no-grad critic pass over the candidates.

The permuted control (`teams.<team>.priority.difficulty_transform = "permuted"`) acts on the pick: the
buffer draws, for each of the control's agents, a permutation of its m·B candidates (`candidate_orders`, from the
buffer's `control_rng`: the control's own seeded stream, saved with the buffer's state, so the candidates and
`select_u` are the draws of the run without the control), and the agent picks with the fresh |δ| + ε of its
candidates read in that order (`LearnerBatch.select_order`). The pick keeps the multiset of priorities, hence the
spread of the IS weights, but which candidate gets which |δ| carries no information about it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmcl.field_docs import documented
from cmcl.replay.rules.contract import Range, Rule
from cmcl.replay.sampling import UniformSampling

CANDIDATES = 4  # m's default: candidates per picked row (LaBER's m = 4 in most of its experiments)


@dataclass(frozen=True)
class LargeBatchOptions:
    """laber's own keys in its team's table (teams.<team>.candidates)."""

    candidates: int = documented(CANDIDATES, "m of laber: the learner draws m·B uniform candidate rows per agent "
                                 "and picks the B of its minibatch among them ∝ their fresh |δ|",
                                 rule=Range("must be >= 2", lambda v: v >= 2))


class LargeBatchSampling(UniformSampling):
    """The candidate batch: uniform over the buffer (the learner picks among the candidates)."""

    name = "laber"


def candidate_orders(shuffled: np.ndarray, size: int, rng: np.random.Generator) -> np.ndarray | None:
    """The permuted control's orders of one minibatch's candidates: int64[N, size], a permutation of 0..size−1
    drawn from `rng` for every agent marked in `shuffled` bool[N] (one vectorised `Generator.permuted` call over
    them, in agent order), the identity for the others; None, and nothing drawn, when no agent is marked."""
    shuffled = np.asarray(shuffled, dtype=bool)
    if not shuffled.any():
        return None
    order = np.broadcast_to(np.arange(size, dtype=np.int64), (shuffled.size, size)).copy()
    order[shuffled] = rng.permuted(order[shuffled], axis=1)
    return order


def select_candidates(priority: np.ndarray, u: np.ndarray, order: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Pick B of M candidates per agent ∝ priority by inverse CDF.

    priority float[N, M] (> 0, finite), u float[N, B] in [0, 1) -> (idx int64[N, B] into the candidates,
    weights float32[N, B] = mean(priority) / priority[idx], LaBER-mean's importance weights).
    order int64[N, M] (the permuted control, `candidate_orders`): candidate j carries the priority of candidate
    order[:, j] (its row's own where order is the identity), so the pick and its weights see the same multiset of
    priorities, shuffled across the candidates."""
    p = np.asarray(priority, dtype=np.float64)
    if p.ndim != 2 or not np.all(np.isfinite(p)) or (p <= 0).any():
        raise ValueError(f"candidate priorities must be finite, > 0 and [N, M], got shape {p.shape}")
    if order is not None:
        order = np.asarray(order, dtype=np.int64)
        if order.shape != p.shape or (np.sort(order, axis=1) != np.arange(p.shape[1])).any():
            raise ValueError(f"candidate order must hold a permutation of the M candidates per agent, [N, M] = "
                             f"{p.shape}, got shape {order.shape}")
        p = np.take_along_axis(p, order, axis=1)
    cdf = np.cumsum(p, axis=1)
    cdf /= cdf[:, -1:]
    idx = np.minimum((cdf[:, None, :] <= np.asarray(u)[:, :, None]).sum(-1), p.shape[1] - 1)  # first cdf > u
    chosen = np.take_along_axis(p, idx, axis=1)
    return idx.astype(np.int64), (p.mean(1, keepdims=True) / chosen).astype(np.float32)


RULE = Rule("laber", "LaBER: each minibatch picked ∝ fresh |δ| among m·B uniform candidates (Lahire et al.)",
            lambda args, options: LargeBatchSampling(args), "laber", 1.0, True, options=LargeBatchOptions,
            draws_uniformly=True, candidates=lambda options: options.candidates, pick=select_candidates)
