"""Typed messages between the roles of Algorithm 1 (numpy only): what each stage hands to the next.

Where it sits: the data flow rollout -> replay -> learner, and replay -> scorers -> replay (one `ScoreWork` out and
one `Scores` back for every scorer: the teachers, the ICM, the online critics the learner hosts). The in-process
scheduler passes these objects between calls; the service passes them between actors as Ray object refs. Producers
build them; the replay server checks what arrives (`check_feedback`, `check_scores` here and
`cmcl.io.records.check_chunk`) and refuses a message that does not fit its buffer, naming the field and the value,
before anything is stored.

Shapes: n minibatches per call, N agents, S rows per minibatch, od / ad obs and action widths, M scored rows,
A_t / A_c teacher / curiosity agents, F folds hosted by one teacher actor, T rows of a chunk.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

ROW_KEYS = ("obs", "act", "rew", "next_obs", "done")  # one joint transition: obs [N, od], act [N, ad], rew [N], ...
PRESENT_KEY = "present"  # bool [N]: the agents a row holds, in learner batches of a buffer with carried rows only
CURIOSITY_KEY = "curiosity"  # float32 [N]: the rows' stored ρ, in learner batches when icm.intrinsic_reward_coef > 0
ACTOR_KEYS = ("obs", "act")  # the row columns the actor step reads (with PRESENT_KEY when the buffer has carried rows)
ACTOR_PREFIX = "actor_"  # an actor's own rows in a learner minibatch: "actor_obs", "actor_act", "actor_present"


class MessageError(ValueError):
    """A message between roles does not match the receiver's layout."""


@dataclass(frozen=True)
class Chunk:
    """Rollout -> replay: B whole episodes of one worker.

    obs / next_obs float32[T, N, od], act float32[T, N, ad], rew float32[T, N], done float32[T, N] (per agent; or
    [T]: one per row), env_index int64[T] (world 0..B−1 of the worker); writer (worker id), incarnation (its
    process life), seq (0, 1, ... per incarnation) make the chunk idempotent; policy_version is the weight version
    that acted.
    """

    obs: np.ndarray
    act: np.ndarray
    rew: np.ndarray
    next_obs: np.ndarray
    done: np.ndarray
    env_index: np.ndarray
    writer: int
    incarnation: str
    seq: int
    policy_version: int = 0

    @property
    def rows(self) -> int:
        return int(self.env_index.shape[0])

    @property
    def worlds(self) -> int:
        """B: the worlds (hence whole episodes) in this chunk."""
        return int(self.env_index.max()) + 1 if self.env_index.size else 0

    @property
    def writer_key(self) -> str:
        """'writer:incarnation', the dedupe key of the replay server."""
        return f"{self.writer}:{self.incarnation}"


@dataclass(frozen=True)
class Rows:
    """Joint transition rows with their buffer slots: rows[k] [*shape, N, ·] for k in ROW_KEYS; slots and
    generations int64[*shape] (a score written back for a slot counts only while its generation is unchanged)."""

    rows: dict[str, np.ndarray]
    slots: np.ndarray
    generations: np.ndarray


@dataclass(frozen=True)
class ActorRows:
    """Replay -> learner, inside a LearnerBatch when some team's actor_batch is "uniform": the actor's own n
    minibatches, drawn uniformly apart from the critic's (actor prioritised replay, Saglam et al. 2023).
    rows: obs [n, N, B, N, od], act [n, N, B, N, ad] (and present bool[n, N, B, N] with carried rows); slots int64
    [n, N, B]; owners bool[N]: the owners whose actor takes them (the others' rows here are their critic's draws,
    and their actor trains on whatever their critic trains on)."""

    rows: dict[str, np.ndarray]
    slots: np.ndarray
    owners: np.ndarray


@dataclass(frozen=True)
class LearnerBatch:
    """Replay -> learner: n per-owner minibatches. rows: obs [n, N, S, N, od], act, rew [n, N, S, N], next_obs,
    done [n, N, S, N], present bool[n, N, S, N] when the buffer holds rows carried from fewer agents
    (run.carry_replay), and curiosity float32[n, N, S, N] (the rows' stored ρ) when icm.intrinsic_reward_coef > 0;
    is_weights float32[n, N, S]; slots / generations int64[n, N, S] (owner v's minibatch is [:, v])."""

    rows: dict[str, np.ndarray]
    is_weights: np.ndarray
    slots: np.ndarray
    generations: np.ndarray
    # LaBER: S = m·B candidates per owner, and one uniform number per row to pick, float64[n, N, B] (else None)
    select_u: np.ndarray | None = None
    # actor_batch = "uniform": the actors' own uniform minibatches (their rows carry no IS weights, no feedback)
    actor: ActorRows | None = None
    # LaBER under the permuted control: the order int64[n, N, S] in which each owner's candidates' fresh |δ| are read
    # to pick (a permutation of 0..S−1 for the control's agents, the identity for the others; else None)
    select_order: np.ndarray | None = None
    # ACL td_self: the online critics' work (a ScoreWork of the ONLINE_TD scorer the learner hosts, no fit rows): with
    # minibatches, the oldest of their scores, scored after the updates; without (count 0), the rows they have not
    # scored yet, scored before anything samples them (ALGORITHM.md A11); else None
    score: ScoreWork | None = None

    @property
    def count(self) -> int:
        return int(self.slots.shape[0])

    def minibatch(self, i: int, importance_weights: bool) -> dict[str, np.ndarray]:
        """The i-th minibatch as `MADDPG.update` takes it ([N, S, ...]); is_weights only if some agent uses them."""
        batch = {k: self.rows[k][i] for k in (*ROW_KEYS, PRESENT_KEY, CURIOSITY_KEY) if k in self.rows}
        if importance_weights:
            batch["is_weights"] = self.is_weights[i]
        return batch


@dataclass(frozen=True)
class RuleScore:
    """One per-row learner score a sampling rule asks for beyond |δ| (its cmcl.replay.rules.contract.LearnerScore,
    e.g. ReLo's "target_td_abs" |y − Q_target|): its name and values float32[n, N, S] >= 0, one per sampled row."""

    name: str
    values: np.ndarray


@dataclass(frozen=True)
class LearnerFeedback:
    """Learner -> replay: |δ| float32[n, N, S] of each sampled (slot, generation), the rules' own learner scores of
    the same rows (`rule_scores`: one RuleScore per score some team's rule asks for), the online critics' Scores of
    the rows it was asked to score (`scores`: values float32[M, N]; ACL td_self), and the last losses per agent.
    n = 0 when the batch held only rows to score."""

    slots: np.ndarray
    generations: np.ndarray
    td_abs: np.ndarray
    losses: dict[str, Any] = field(default_factory=dict)
    incarnation: str = ""  # the learner actor's incarnation id
    rule_scores: tuple[RuleScore, ...] = ()
    # the online critics' |y − Q_v(s, a)| of LearnerBatch.score's rows (ACL td_self); else None
    scores: Scores | None = None


DIFFICULTY, CURIOSITY, ONLINE_TD = "difficulty", "curiosity", "td_abs"  # the score columns scorers write


@dataclass(frozen=True)
class Scorer:
    """Which scorer: the score column it writes (DIFFICULTY: a group of K-fold teachers, eqs. 10-11; CURIOSITY: the
    ICM, eq. 18; ONLINE_TD: the learner's online critics, ACL td_self) and, for a teacher group, the folds it hosts
    (a teacher never scores its own fold, eq. 9)."""

    column: str
    folds: tuple[int, ...] = ()


@dataclass(frozen=True)
class ScoreWork:
    """Replay -> a scorer: rows to fit and rows to score, at learner update `updates` (the update clock).

    fit: rows [steps, ...] to fit ({} when the scorer fits elsewhere: the online critics train in the learner's
    updates): a teacher group's [steps, B, F, S, N, ·] (fit[:, :, i] all from fold folds[i]; B = 1, one batch shared
    by the agents, or A_t under teachers.fit_batch = "per_agent"), the ICM's [steps, S, N, ·] (obs, act, next_obs);
    fit_slots int64 of fit's leading shape (None without fit rows); score: the rows to score, M of them."""

    scorer: Scorer
    fit: dict[str, np.ndarray]
    fit_slots: np.ndarray | None
    score: Rows
    updates: int


@dataclass(frozen=True)
class Scores:
    """A scorer -> replay: the values of one score column for the scored (slot, generation) pairs.

    slots / generations int64[M]; values float32[M, A] (A: the agents of the column: A_c for curiosity, N for the
    online critics) or, for a teacher group, its errors float32[M, A_t, F] over its F folds (eq. 10); stamp: the
    learner update the work was handed out at; loss: the scorer's last fit loss; incarnation: the sending actor's
    process life ("" when none)."""

    scorer: Scorer
    slots: np.ndarray
    generations: np.ndarray
    values: np.ndarray
    stamp: int
    loss: float = 0.0
    incarnation: str = ""


def _check_rows(name: str, slots: np.ndarray, generations: np.ndarray, values: np.ndarray, width: tuple[int, ...]
                ) -> None:
    """slots / generations int[M] and values finite float[M, *width], or MessageError naming the field."""
    m = np.shape(slots)
    if len(m) != 1 or np.shape(generations) != m:
        raise MessageError(f"{name}.slots / generations must be int[M] of one length, got shapes "
                           f"{np.shape(slots)} and {np.shape(generations)}")
    if np.shape(values) != (*m, *width):
        raise MessageError(f"{name} values must have shape {(*m, *width)}, got {np.shape(values)}")
    if not np.all(np.isfinite(values)):
        raise MessageError(f"{name} values must be finite, got {float(values[~np.isfinite(values)].ravel()[0])!r}")


def _check_incarnation(name: str, incarnation: Any) -> None:
    """An incarnation id is a short string (services.runtime.common.new_incarnation: 12 hex digits; "" inline)."""
    if not isinstance(incarnation, str) or len(incarnation) > 64:
        raise MessageError(f"{name}.incarnation must be a string of at most 64 characters, got {incarnation!r:.80}")


def check_scores(msg: Any, width: dict[str, int], num_folds: int) -> Scores:
    """The message if it is a Scores of a known column (`width`: its agents A per column) whose values have that
    column's shape ([M, A], a teacher group's [M, A_t, F] over valid folds); MessageError otherwise."""
    if not isinstance(msg, Scores):
        raise MessageError(f"scores must be a Scores, got {type(msg).__name__}")
    scorer = msg.scorer
    if not isinstance(scorer, Scorer) or scorer.column not in width:
        raise MessageError(f"Scores.scorer must be a Scorer of a column in {sorted(width)}, got {scorer!r:.80}")
    _check_incarnation("Scores", msg.incarnation)
    shape: tuple[int, ...] = (width[scorer.column],)
    if scorer.column == DIFFICULTY:
        if not scorer.folds or any(not 0 <= f < num_folds for f in scorer.folds):
            raise MessageError(f"Scores.scorer.folds must lie in 0..{num_folds - 1}, got {list(scorer.folds)}")
        shape = (*shape, len(scorer.folds))
    _check_rows(f"Scores.values ({scorer.column})", msg.slots, msg.generations, msg.values, shape)
    return msg


def check_feedback(msg: Any, num_agents: int) -> LearnerFeedback:
    """The message if it is a LearnerFeedback of [n, N, S] arrays; MessageError otherwise."""
    if not isinstance(msg, LearnerFeedback):
        raise MessageError(f"learner feedback must be a LearnerFeedback, got {type(msg).__name__}")
    _check_incarnation("LearnerFeedback", msg.incarnation)
    shape = np.shape(msg.slots)
    if len(shape) != 3 or shape[1] != num_agents or np.shape(msg.generations) != shape:
        raise MessageError(f"LearnerFeedback.slots / generations must be [n, N={num_agents}, S], got "
                           f"{np.shape(msg.slots)} and {np.shape(msg.generations)}")
    _check_rows("LearnerFeedback.td_abs", np.ravel(msg.slots), np.ravel(msg.generations), np.ravel(msg.td_abs), ())
    for score in msg.rule_scores:
        if not isinstance(score, RuleScore) or np.shape(score.values) != shape:
            raise MessageError(f"LearnerFeedback.rule_scores must hold RuleScores of shape {shape}, got "
                               f"{type(score).__name__} {getattr(score, 'name', '')!r} of shape "
                               f"{np.shape(getattr(score, 'values', None))}")
        _check_rows(f"LearnerFeedback.rule_scores[{score.name!r}]", np.ravel(msg.slots), np.ravel(msg.generations),
                    np.ravel(score.values), ())
    return msg


@dataclass(frozen=True)
class PacingStatus:
    """Work each role may be given now (the first fields of `ReplayStatus`; built by
    `cmcl.replay.pacing.Pacing.status`). allowed_updates: learner updates;
    allowed_inserts: transitions; update_deficit / scoring_deficit: learner updates, teacher and ICM fit steps still
    owed to their ratios (< 1: caught up); teacher_allowed: fit steps per fold [K]; icm_allowed: ICM fit steps;
    updates_held_by: why allowed_updates is 0 ("" when it is not): "warmup" (the buffer is still filling),
    "env_steps" (the learner is its slack ahead of the env steps: it waits for data; said even when the scores hold
    it too) or "scores" (it is the slack ahead of a teacher fold or the ICM: it waits for scores).
    Every allowance is 0 before the warm-up ends, except the inserts that fill it."""

    allowed_updates: int
    allowed_inserts: int
    update_deficit: float
    scoring_deficit: float
    teacher_allowed: tuple[int, ...]
    icm_allowed: int
    updates_held_by: str


@dataclass(frozen=True)
class ReplayStatus(PacingStatus):
    """Replay -> supervisor, with every reply of the replay server: how much work each role may be given now (the
    fields of `PacingStatus`: allowed_updates, allowed_inserts, update_deficit, scoring_deficit,
    teacher_allowed [K], icm_allowed, updates_held_by) and the counters the supervisor shows.

    size: transitions stored; env_steps, episodes, updates: totals so far; lam: the curriculum factor λ;
    incarnation: the server's process life. accepted / error: set by the calls that store something (insert, score
    writes): rows accepted, and "reason: detail" when the input was refused.
    """

    size: int
    env_steps: int
    episodes: int
    updates: int
    lam: float
    incarnation: str
    accepted: int | None = None
    error: str | None = None

    def counters(self) -> dict[str, Any]:
        """The counters as a plain mapping (metrics rows, summaries): episodes, env_steps, updates, size, lambda."""
        return {"episodes": self.episodes, "env_steps": self.env_steps, "updates": self.updates, "size": self.size,
                "lambda": self.lam}
