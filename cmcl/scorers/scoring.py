"""The scoring state of the curriculum: who scored which replay row and when, and the one rule that picks the rows to
(re)score next (ALGORITHM.md §3.2, §3.4, §3.8, §3.9, A11).

Where it sits: one `ScoringState` beside the `ReplayBuffer` of the replay server (`services.roles.replay_server`),
whichever scheduler runs it. Scores come in through `write_difficulty` (teacher errors, eqs. 10–11),
`write_curiosity` (ρ, eq. 18) and `write_online_td` (ACL td_self's |δ|); each writes the buffer's score column and
stamps the rows with the learner update the score was made at. The buffer's columns hold the scores; this object
holds the stamps, the teachers' per-fold errors (`cmcl.scorers.difficulty.DifficultyTable`) and the insertion times.

The rescoring rule (`rows_to_score`): the rows whose score from the given scorers is oldest, never-scored rows first.
The replay server asks it for the rows of one teacher group (a teacher never scores its own fold, eq. 9) or of the
ICM, `service.score_rows_per_call` per call, and, for the online critics the learner hosts (ACL td_self), every
never-scored row topped up to that many with the oldest scores (§3.8's periodic rescoring, spread over the calls).
The online critics score each chunk when it is inserted, and `unscored` holds the learner's updates while a row
waits for them (A11: score at insertion), so a td_self row is never sampled on its provisional priority.
Oldest first rather than a cursor walking the slots: the asynchronous teacher groups of the service cannot share a
cursor, and a cursor would spend rescoring on rows that were scored at insertion a few updates ago while older
scores wait. Either way a full buffer of |D| rows is rescored every |D| / rows updates at most.

Shapes: capacity C slots, K folds, A_t teacher agents, A_c curiosity agents, M valid rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cmcl.replay.buffer import ReplayBuffer
from cmcl.scorers.difficulty import DifficultyTable, ScoreStamps


def online_critics_score(layout: Any) -> bool:
    """Whether some agent's difficulty is the online critics' |δ| (ACL td_self) of a `cmcl.system.AgentLayout`: the
    learner then hosts the online critics' scorer."""
    return "td_abs" in layout.difficulty_source


def oldest_first(candidates: np.ndarray, stamps: np.ndarray, count: int) -> np.ndarray:
    """Up to `count` of candidates int64[M] whose stamps float[M] are oldest (never scored, −1, first), sorted by
    slot."""
    if candidates.size <= count:
        return candidates
    pick = np.argpartition(stamps, count - 1)[:count]
    return np.sort(candidates[pick])


@dataclass(frozen=True)
class ScoringSummary:
    """How much of the buffer is scored and how old the scores are (fields named as in the replay server's report,
    `services.observability.report_schema.ReplayReport`); None where the run has no such scorer or nothing to show. Ages
    in learner updates, uniform subsamples of the rows."""

    score_coverage: float | None = None  # fraction of the rows with a teacher difficulty for every teacher agent
    fold_score_coverage: dict[str, float] | None = None  # the same per fold {fold: fraction}
    score_age: np.ndarray | None = None  # float64[≤ keep] updates since each teacher score
    curiosity_age: np.ndarray | None = None  # float64[≤ keep] updates since each curiosity score
    sample_age: np.ndarray | None = None  # float64[≤ keep] updates since insertion of the rows last sampled


class ScoringState:
    """Score stamps, teacher errors and insertion times of a replay of `capacity` slots.

    Args: capacity C; num_folds K; teacher_agents int64[A_t] and icm_agents int64[A_c] (the agents whose priorities
    need teacher difficulty / curiosity); online_td: some agent's difficulty is the online critics' |δ| (td_self).
    """

    def __init__(self, capacity: int, num_folds: int, teacher_agents: np.ndarray, icm_agents: np.ndarray,
                 online_td: bool = False):
        self.teacher_agents = np.asarray(teacher_agents, np.int64)
        self.icm_agents = np.asarray(icm_agents, np.int64)
        self.online_td = bool(online_td)
        self.difficulty = DifficultyTable(capacity, self.teacher_agents.size, num_folds)
        self.curiosity_stamps = ScoreStamps(capacity, 1)
        self.online_td_stamps = ScoreStamps(capacity, 1)
        self.inserted_at = np.zeros(capacity, np.int64)  # learner updates when each slot was written
        self.sample_ages = np.zeros(0)  # updates since insertion of (a subsample of) the rows last sampled

    @classmethod
    def for_layout(cls, layout: Any, capacity: int, num_folds: int) -> ScoringState:
        """The scoring state of a `cmcl.system.AgentLayout`."""
        return cls(capacity, num_folds, layout.teacher_agents, layout.icm_agents,
                   online_td=online_critics_score(layout))

    # ------------------------------------------------------------------ insertion and sampling times
    def inserted(self, slots: np.ndarray, updates: int) -> None:
        """Slots int64[T] (−1 = overwritten within the chunk, skipped) were written at learner update `updates`."""
        slots = np.asarray(slots)
        self.inserted_at[slots[slots >= 0]] = int(updates)

    def sampled(self, slots: np.ndarray, updates: int, rng: np.random.Generator, keep: int) -> None:
        """The learner was handed slots int64[...] at learner update `updates`: keep a uniform subsample of at most
        `keep` of their ages (updates since insertion) for the report."""
        ages = (int(updates) - self.inserted_at[np.asarray(slots).ravel()]).astype(np.float64)
        self.sample_ages = ages[rng.integers(0, ages.size, min(ages.size, keep))]

    # ------------------------------------------------------------------ scores in
    def write_difficulty(self, replay: ReplayBuffer, slots: np.ndarray, generations: np.ndarray,
                         folds: Sequence[int], errors: np.ndarray, stamp: int) -> tuple[int, int]:
        """Record the errors float32[M, A_t, F] of the teachers of `folds` (eq. 10) made at learner update `stamp`
        and store c (eq. 11) of the rows. Stale (slot, generation) pairs are dropped.
        Returns (rows whose c was stored, stale rows dropped)."""
        slots, generations = np.asarray(slots, dtype=np.int64), np.asarray(generations, dtype=np.int64)
        fresh = replay.storage.fresh_mask(slots, generations)
        s, g = slots[fresh], generations[fresh]
        row_fold = replay.storage.fold[s]
        self.difficulty.record(s, g, row_fold, list(folds), np.asarray(errors)[fresh], stamp)
        c, ok = self.difficulty.difficulty(s, g, row_fold)
        stored = replay.update_scores("difficulty", s[ok], g[ok], c[ok], agents=self.teacher_agents)
        return stored, int((~fresh).sum())

    def write_curiosity(self, replay: ReplayBuffer, slots: np.ndarray, generations: np.ndarray, rho: np.ndarray,
                        stamp: int) -> tuple[int, int]:
        """Store ρ float32[M, A_c] (eq. 18) of fresh rows, made at learner update `stamp`. Returns (accepted, stale)."""
        return self._write(replay, "curiosity", self.curiosity_stamps, self.icm_agents, slots, generations, rho, stamp)

    def write_online_td(self, replay: ReplayBuffer, slots: np.ndarray, generations: np.ndarray, td_abs: np.ndarray,
                        stamp: int) -> tuple[int, int]:
        """Store the online critics' |δ| float32[M, N] of every agent in the "td_abs" column (ACL td_self's
        difficulty, §5), made at learner update `stamp`. Returns (accepted, stale)."""
        agents = np.arange(replay.n_agents)
        return self._write(replay, "td_abs", self.online_td_stamps, agents, slots, generations, td_abs, stamp)

    @staticmethod
    def _write(replay: ReplayBuffer, column: str, stamps: ScoreStamps, agents: np.ndarray, slots: np.ndarray,
               generations: np.ndarray, values: np.ndarray, stamp: int) -> tuple[int, int]:
        slots, generations = np.asarray(slots, dtype=np.int64), np.asarray(generations, dtype=np.int64)
        fresh = replay.storage.fresh_mask(slots, generations)
        accepted = replay.update_scores(column, slots, generations, values, agents=agents)
        stamps.mark(slots[fresh], generations[fresh], 0, stamp)
        return accepted, int(slots.size) - accepted

    # ------------------------------------------------------------------ the rescoring rule
    def score_stamps(self, replay: ReplayBuffer, folds: Sequence[int] = (), curiosity: bool = False,
                     online_td: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(valid slots int64[M], stamp float64[M]): the learner update of each row's oldest score among the given
        scorers (the teachers of `folds`, the ICM, the online critics), −1 if one of them has not scored the row's
        current content, +inf if none of them may score it (only its own fold's teacher was asked)."""
        valid = replay.valid_slots()
        gens = replay.generations(valid)
        parts = [np.full((valid.size, 1), np.inf)]
        if len(folds):
            folds = np.asarray(folds, np.int64)
            teacher = self.difficulty.stamps(valid, gens)[:, folds].astype(np.float64)  # [M, F]
            teacher[replay.storage.fold[valid][:, None] == folds[None, :]] = np.inf  # own fold: never (eq. 9)
            parts.append(teacher)
        for asked, stamps in ((curiosity, self.curiosity_stamps), (online_td, self.online_td_stamps)):
            if asked:
                parts.append(stamps.stamps(valid, gens).astype(np.float64))
        return valid, np.concatenate(parts, axis=1).min(axis=1)

    def unscored(self, replay: ReplayBuffer, folds: Sequence[int] = (), curiosity: bool = False,
                 online_td: bool = False) -> int:
        """How many valid rows one of the given scorers has not scored in their current content (a row in the
        online critics' case is sampled only once it has: ALGORITHM.md A11)."""
        return int((self.score_stamps(replay, folds, curiosity, online_td)[1] < 0).sum())

    def rows_to_score(self, replay: ReplayBuffer, count: int, folds: Sequence[int] = (), curiosity: bool = False,
                      online_td: bool = False, every_unscored: bool = False) -> np.ndarray:
        """The rule: the `count` rows whose score from the given scorers is oldest, never-scored rows first (more
        than `count` if `every_unscored` and more rows than that have never been scored). int64[·] sorted slots."""
        valid, stamp = self.score_stamps(replay, folds, curiosity, online_td)
        useful = np.isfinite(stamp)
        valid, stamp = valid[useful], stamp[useful]
        if every_unscored:
            count = max(int(count), int((stamp < 0).sum()))
        return oldest_first(valid, stamp, int(count))

    # ------------------------------------------------------------------ report
    def summary(self, replay: ReplayBuffer, updates: int, rng: np.random.Generator, keep: int) -> ScoringSummary:
        """Coverage and score ages now (`updates`: learner updates so far); the ages are uniform subsamples of at
        most `keep` rows drawn from `rng` (teacher ages first, then curiosity ages)."""
        size = replay.size
        if not size:
            return ScoringSummary(sample_age=self.sample_ages if self.sample_ages.size else None)
        valid = replay.valid_slots()
        gens = replay.generations(valid)
        out: dict[str, Any] = {}
        if self.teacher_agents.size:
            scored = replay.storage.scored["difficulty"][:size][:, self.teacher_agents].all(1)
            folds = replay.storage.fold[:size]
            out["score_coverage"] = float(scored.mean())
            out["fold_score_coverage"] = {str(f): float(scored[folds == f].mean()) for f in np.unique(folds)}
            times = self.difficulty.stamps(valid, gens)
            out["score_age"] = _age_sample(updates - times[times >= 0], rng, keep)
        if self.icm_agents.size:
            times = self.curiosity_stamps.stamps(valid, gens)[:, 0]
            out["curiosity_age"] = _age_sample(updates - times[times >= 0], rng, keep)
        return ScoringSummary(**out, sample_age=self.sample_ages if self.sample_ages.size else None)

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        """{"difficulty": DifficultyTable state, "curiosity_stamps", "online_td_stamps": ScoreStamps states,
        "inserted_at": int64[C]} (keys of the runners' replay snapshots)."""
        return {"difficulty": self.difficulty.state_dict(), "curiosity_stamps": self.curiosity_stamps.state_dict(),
                "online_td_stamps": self.online_td_stamps.state_dict(), "inserted_at": self.inserted_at.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore `state_dict()` output, validated before anything changes."""
        capacity = self.inserted_at.size
        difficulty = DifficultyTable(capacity, self.teacher_agents.size, self.difficulty.num_folds)
        difficulty.load_state_dict(state["difficulty"])
        stamps = {}
        for name in ("curiosity_stamps", "online_td_stamps"):
            stamps[name] = ScoreStamps(capacity, 1)
            stamps[name].load_state_dict(state[name])
        inserted_at = np.asarray(state["inserted_at"], np.int64)
        if inserted_at.shape != (capacity,):
            raise ValueError(f"inserted_at has shape {inserted_at.shape}, expected ({capacity},)")
        self.difficulty, self.inserted_at = difficulty, inserted_at.copy()
        self.curiosity_stamps, self.online_td_stamps = stamps["curiosity_stamps"], stamps["online_td_stamps"]


def _age_sample(ages: np.ndarray, rng: np.random.Generator, keep: int) -> np.ndarray | None:
    """A uniform subsample (with replacement) of at most `keep` of ages, or None if there are none."""
    return ages[rng.integers(0, ages.size, min(ages.size, keep))] if ages.size else None
