"""Cross-validated difficulty c of eq. (11): the K teachers' latest errors on each row, summed over the blind ones.

Where it sits: between the teachers and the replay's "difficulty" score column. Teachers (`cmcl.scorers.teachers`)
return per-teacher errors e_{a,j,i} (eq. 10); a `DifficultyTable` keeps the latest error of every teacher i on every
buffer slot j, keyed by the slot's generation, and turns them into c_{a,j} over the teachers that never saw j
(i != f(j), eq. 11) and have scored j. The inline loop records all K teachers at once, which gives the plain sum
of eq. (11); the service's teacher actors score asynchronously, one fold group at a time, and c is then
(K−1)·mean over the blind teachers that have scored j so far (ALGORITHM.md §3.9). Numpy only (the replay server
never loads torch).

Shapes: capacity C slots, A_t teacher-using agents, K folds; errors of one scoring pass are float32[M, A_t, F] for
the F folds that scored.
"""

from __future__ import annotations

import numpy as np


def cross_validated_difficulty(errors: np.ndarray, row_fold: np.ndarray, scored: np.ndarray | None = None
                               ) -> tuple[np.ndarray, np.ndarray]:
    """c_{j,a} = (K−1)/|B_j| · Σ_{i∈B_j} e_{j,a,i}, B_j = {i ≠ f(j) that have scored j} (eq. 11).

    errors float32[M, A, K]; row_fold int64[M] in 0..K−1; scored bool[M, K] (default: every teacher has scored).
    With every blind teacher scored, |B_j| = K−1 and c is eq. (11)'s sum. Returns (c float32[M, A], ok bool[M]:
    some blind teacher has scored j); c is 0 where not ok.
    """
    k = errors.shape[-1]
    blind = np.asarray(row_fold)[:, None] != np.arange(k)[None, :]  # [M, K]: mask M[j, i] = 1[f(j) != i]
    if scored is not None:
        blind &= scored
    count = blind.sum(1)
    total = (errors * blind[:, None, :]).sum(-1)  # [M, A]
    scale = np.where(count > 0, (k - 1) / np.maximum(count, 1), 0.0).astype(errors.dtype)
    return total * scale[:, None], count > 0


class ScoreStamps:
    """When each of `columns` scorers last scored each slot: the learner update and the slot generation it was for.

    A slot overwritten by a new transition (a new generation) counts as never scored, whatever its old stamps.
    """

    def __init__(self, capacity: int, columns: int):
        self.generation = np.full((capacity, columns), -1, np.int64)  # slot generation the score is for
        self.stamp = np.full((capacity, columns), -1, np.int64)  # learner updates when it was made

    def mark(self, slots: np.ndarray, generations: np.ndarray, column: int, stamp: int) -> None:
        """Scorer `column` has scored the given (slot, generation) rows at learner update `stamp`."""
        self.generation[slots, column] = generations
        self.stamp[slots, column] = int(stamp)

    def scored(self, slots: np.ndarray, generations: np.ndarray) -> np.ndarray:
        """bool[M, columns]: scorer i has scored the current content (generation) of slot j."""
        return self.generation[slots] == np.asarray(generations)[:, None]

    def stamps(self, slots: np.ndarray, generations: np.ndarray) -> np.ndarray:
        """int64[M, columns] learner update at which scorer i last scored the current content of slot j (−1: never)."""
        return np.where(self.scored(slots, generations), self.stamp[slots], -1)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"generation": self.generation, "stamp": self.stamp}

    def load_state_dict(self, state: dict) -> None:
        """Restore `state_dict()` output (same shape), validated before anything changes."""
        staged = {name: _same_shape(f"score stamps {name}", state[name], getattr(self, name))
                  for name in ("generation", "stamp")}
        self.generation, self.stamp = staged["generation"], staged["stamp"]


class DifficultyTable:
    """The latest error of each teacher on each slot, with the learner update it was made at.

    Args: capacity C (replay slots), num_agents A_t (teacher-using agents), num_folds K.
    """

    def __init__(self, capacity: int, num_agents: int, num_folds: int):
        self.error = np.zeros((capacity, num_agents, num_folds), np.float32)  # e of teacher i on slot j
        self.clock = ScoreStamps(capacity, num_folds)

    @property
    def num_folds(self) -> int:
        return self.error.shape[2]

    def record(self, slots: np.ndarray, generations: np.ndarray, row_fold: np.ndarray, folds: list[int],
               errors: np.ndarray, stamp: int) -> int:
        """Store errors float32[M, A_t, F] of the teachers of `folds` on fresh rows; a teacher's error on a row of
        its own fold is never stored (it never counts, eq. 11). Returns the (row, teacher) entries stored."""
        stored = 0
        for i, f in enumerate(folds):
            blind = row_fold != f
            self.error[slots[blind], :, f] = errors[blind, :, i]
            self.clock.mark(slots[blind], generations[blind], f, stamp)
            stored += int(blind.sum())
        return stored

    def stamps(self, slots: np.ndarray, generations: np.ndarray) -> np.ndarray:
        """int64[M, K] learner update at which teacher i last scored the current content of slot j (−1: never)."""
        return self.clock.stamps(slots, generations)

    def difficulty(self, slots: np.ndarray, generations: np.ndarray, row_fold: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """(c float32[M, A_t], ok bool[M]) of rows from the stored errors (eq. 11, see `cross_validated_difficulty`)."""
        return cross_validated_difficulty(self.error[slots], row_fold, self.clock.scored(slots, generations))

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"error": self.error, **self.clock.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        """Restore `state_dict()` output (same capacity, agents and folds), validated before anything changes."""
        error = _same_shape("difficulty table error", state["error"], self.error)
        self.clock.load_state_dict(state)
        self.error = error


def _same_shape(name: str, value, like: np.ndarray) -> np.ndarray:
    """value as an array of like's dtype, or ValueError naming `name` if its shape differs."""
    arr = np.asarray(value)
    if arr.shape != like.shape:
        raise ValueError(f"{name} has shape {arr.shape}, expected {like.shape}")
    return arr.astype(like.dtype)
