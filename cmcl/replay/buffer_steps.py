"""The replay side of each step of Algorithm 1 (ALGORITHM.md §3.8): what is drawn from the buffer, what is written back.

Where it sits: one implementation, two schedulers: `services.roles.replay_server` calls these functions when a role asks
for work or sends results. The learner side of each step (networks) is `cmcl.learners.network_steps`. Numpy only.

  learner minibatches ...... sample_owner_batches       -> LearnerBatch [n, N, S]      (per-agent samplers, eq. 20;
                                                           with the actors' own uniform rows, actor_batch = "uniform";
                                                           LaBER's candidate orders under the permuted control)
  learner feedback ......... apply_learner_feedback      <- LearnerFeedback (per-row losses to each sampler)
  teacher fit rows ......... fold_batch_slots            -> slots [steps, B, F, S] from each fold only (eq. 9)
  ICM fit rows ............. uniform_slots               -> slots, drawn uniformly (§3.4)
  rows to (re)score, scores written back: the scoring state, `cmcl.scorers.scoring.ScoringState`
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from cmcl.replay.buffer import ReplayBuffer
from cmcl.replay.messages import ACTOR_KEYS, PRESENT_KEY, ROW_KEYS, ActorRows, LearnerBatch, LearnerFeedback, Rows
from cmcl.replay.rules.laber import candidate_orders
from cmcl.replay.sampling import UniformSampling

UNIFORM = UniformSampling()  # the actors' own minibatches are maddpg's draw: P(j) = 1/|D|


def rows_at(replay: ReplayBuffer, slots: np.ndarray, keys: Sequence[str] = ROW_KEYS) -> dict[str, np.ndarray]:
    """Joint rows of slots int64[*shape]: rows[k] [*shape, N, ·] (done [*shape, N])."""
    flat = replay.get(np.asarray(slots).reshape(-1))
    return {k: flat[k].reshape(*np.shape(slots), *flat[k].shape[1:]) for k in keys}


def score_rows(replay: ReplayBuffer, slots: np.ndarray) -> Rows:
    """Rows int64[M] to score, with their generations (scores come back keyed by (slot, generation))."""
    slots = np.asarray(slots, dtype=np.int64)
    return Rows(rows_at(replay, slots), slots, replay.generations(slots))


def sample_owner_batches(replay: ReplayBuffer, count: int, batch_size: int, rngs: Sequence[np.random.Generator],
                         betas: Sequence[float], candidates: int = 1, uniform_actor: Sequence[bool] = (),
                         permuted_select: Sequence[bool] = ()) -> LearnerBatch:
    """`count` learner minibatches: every agent v draws its own S slots from its own P_v (eq. 20) per minibatch.

    betas: IS exponent per agent (0: weights of 1). candidates: m > 1 (LaBER) draws S = m·batch_size candidates
    per owner, then one uniform number per row to pick from each agent's own generator (`LearnerBatch.select_u`).
    permuted_select: bool per agent (`AgentLayout.permuted_select`: LaBER under the permuted control): with m > 1,
    a permutation of each marked agent's S candidates per minibatch from the buffer's `control_rng`, the order the
    learner reads their |δ| in to pick (`LearnerBatch.select_order`; None, and nothing drawn, when none is marked).
    uniform_actor: bool per agent (actor_batch = "uniform"): those agents then draw, after their critic's rows, a
    minibatch of batch_size rows uniformly from their own generator for their actor (`LearnerBatch.actor`; None
    when no agent is marked, and nothing more is drawn).
    Returns a LearnerBatch of [count, N, S] arrays, with the agents' presence when the buffer holds rows carried
    from fewer agents (run.carry_replay).
    """
    owners = np.asarray(uniform_actor, dtype=bool) if any(uniform_actor) else None
    shuffled = np.asarray(permuted_select, dtype=bool) if candidates > 1 and any(permuted_select) else None
    draws, picks, orders, actor = [], [], [], []
    for _ in range(count):
        draws.append(replay.sample_all(batch_size * candidates, list(rngs), beta=list(betas)))
        if candidates > 1:
            picks.append(np.stack([rng.random(batch_size) for rng in rngs]))
        if shuffled is not None:  # the control's own stream: the sampler streams stay as without the control
            orders.append(candidate_orders(shuffled, batch_size * candidates, replay.control_rng))
        if owners is not None:
            actor.append(actor_slots(replay, draws[-1][0][:, :batch_size], rngs, owners))
    slots = np.stack([d[0] for d in draws])  # [n, N, S]
    present = (PRESENT_KEY,) if replay.storage.absent_rows else ()
    actor_rows = None
    if owners is not None:
        own = np.stack(actor)  # [n, N, B]
        actor_rows = ActorRows(rows_at(replay, own, (*ACTOR_KEYS, *present)), own, owners)
    return LearnerBatch(rows_at(replay, slots, (*ROW_KEYS, *present)), np.stack([d[1] for d in draws]), slots,
                        replay.generations(slots.reshape(-1)).reshape(slots.shape),
                        np.stack(picks) if picks else None, actor_rows, np.stack(orders) if orders else None)


def actor_slots(replay: ReplayBuffer, critic: np.ndarray, rngs: Sequence[np.random.Generator], owners: np.ndarray
                ) -> np.ndarray:
    """The actors' rows of one minibatch: int64[N, B], owner v's B slots drawn uniformly over the buffer from its
    own generator where owners[v], else its critic's first B draws `critic` int64[N, B] (the learner then trains
    that actor on whatever its critic trains on)."""
    out = critic.copy()
    for agent in np.flatnonzero(owners):
        out[agent] = UNIFORM.sample(critic.shape[1], replay.size, rngs[agent], 0.0)[0]
    return out


def apply_learner_feedback(replay: ReplayBuffer, layout: Any, feedback: LearnerFeedback) -> tuple[int, bool]:
    """The learner's per-row scores of every sampled row (|δ| and the rules' own, `LearnerFeedback.rule_scores`), to
    each agent's sampler (`ReplayBuffer.feedback`): PER and ReLo set their priorities from them, ACL td_self and the
    reducible held-out rule write the "td_abs" column. Only the scores the layout's rules ask for are passed
    (`layout.learner_scores`).

    Stale (slot, generation) pairs are dropped. Returns (stale pairs dropped, whether a score column changed,
    i.e. priorities need a recompute).
    """
    stale, scores_changed = 0, False
    if not layout.learner_scores:
        return stale, scores_changed
    given = {"td_abs": feedback.td_abs, **{score.name: score.values for score in feedback.rule_scores}}
    columns = {name: np.asarray(given[name]) for name in layout.learner_scores}
    for agent in range(layout.num_agents):
        s = feedback.slots[:, agent].reshape(-1)
        g = feedback.generations[:, agent].reshape(-1)
        accepted, changed = replay.feedback(agent, s, g, {k: v[:, agent].reshape(-1) for k, v in columns.items()})
        stale += s.size - accepted
        scores_changed |= changed
    return stale, scores_changed


def fold_draw_indices(fold: np.ndarray, folds: Sequence[int], batch_size: int, rng: np.random.Generator,
                      draws: int = 1, steps: int = 1) -> np.ndarray:
    """Uniform draws (with replacement) of rows from each fold only: fold int64[M] (the fold of every row) ->
    int64[steps, draws, F, S] indices into it, with fold[idx[:, :, i]] == folds[i]. ValueError if a fold is empty."""
    fold = np.asarray(fold, dtype=np.int64)
    folds = np.asarray(folds, dtype=np.int64)
    counts = np.bincount(fold, minlength=int(folds.max(initial=0)) + 1)
    if fold.size == 0 or (counts[folds] == 0).any():
        raise ValueError(f"every fold of {folds.tolist()} needs rows; rows per fold = {counts.tolist()}")
    order = np.argsort(fold, kind="stable")  # rows grouped by fold
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[folds]  # [F]
    have = counts[folds][None, None, :, None]
    u = rng.random((steps, draws, folds.size, batch_size))
    return order[starts[None, None, :, None] + np.minimum((u * have).astype(np.int64), have - 1)]


def teacher_fit_draws(fit_batch: str, teacher_agents: np.ndarray) -> int:
    """Fit batches per fold and step (`teachers.fit_batch`): 1 ("shared": one batch for all the fold's agents) or
    A_t ("per_agent": one per teacher agent), as both runners draw them."""
    return 1 if fit_batch == "shared" else len(teacher_agents)


def fold_batch_slots(replay: ReplayBuffer, folds: Sequence[int], batch_size: int, rng: np.random.Generator,
                     draws: int = 1, steps: int = 1) -> np.ndarray:
    """Teacher fit slots, drawn uniformly from each fold only (eq. 9, §3.2): int64[steps, draws, F, S] with
    fold(slots[:, :, i]) == folds[i]; draws = 1 shares one batch per fold among the agents' teachers, draws = A_t
    gives every agent its own."""
    valid = replay.valid_slots()
    return valid[fold_draw_indices(replay.storage.fold[valid], folds, batch_size, rng, draws, steps)]


def uniform_slots(replay: ReplayBuffer, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """int64[shape] slots drawn uniformly from the valid rows (the ICM's fit batches, §3.4)."""
    return replay.valid_slots()[rng.integers(0, replay.size, shape)]
