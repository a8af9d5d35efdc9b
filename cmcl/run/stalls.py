"""Where a navigation policy misses landmarks, and how long a run sat on a plateau (the stall analysis).

Where it sits: read-only analysis. `cmcl.run.evaluate` calls `miss_anatomy` on the final step of its held-out worlds
(sparse navigation only) and prints it; the experiment report calls `plateau_episodes` on a run's episode rows.

A run "stalls" when its 100-episode moving average of coverage sits at about three landmarks of four for a long
time. At N agents and N landmarks a landmark stays uncovered at the final step only if some agent is on no landmark
of its own, so each world that misses a landmark is put in one of three classes by what its agents do there:

* **crowded**: an agent shares every landmark it is on with another agent (two agents on one landmark);
* **short**: no agent crowds, and an agent that is on no landmark ends within 2 cover radii of an uncovered one;
* **far**: no agent crowds, and every agent on no landmark ends farther away than that.

Agents that end at a wall (within 1e-3 of ARENA_HALF minus their radius) are counted too: a policy that pins an
agent to a wall is a known way for MPE navigation to stall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmcl.envs.common import ARENA_HALF
from cmcl.envs.metrics import success
from cmcl.run.plots import moving_average

MISS_CLASSES = ("crowded", "short", "far")
NEAR_RADII = 2.0  # "short": within this many cover radii of an uncovered landmark
WALL_TOLERANCE = 1e-3


@dataclass(frozen=True)
class MissAnatomy:
    """Final-step anatomy of B worlds (shares are fractions in [0, 1]).

    worlds: B. missed_share: worlds with at least one uncovered landmark. missed_by_class: {class: share of the
    missing worlds} over MISS_CLASSES (sums to 1 when any world misses). agent_idle_share: float[N], per agent the
    share of worlds where it is on no landmark; agent_crowding_share: float[N], where it is only on landmarks
    another agent is on too; agent_wall_share: float[N], where it ends at a wall. idle_distance_median: the median
    distance from an idle agent to its nearest uncovered landmark (world units; nan when none).
    covered_unmatched_share: worlds with every landmark covered but not each by an agent of its own (no perfect
    matching of landmarks to the agents covering them: one agent covers two landmarks no other agent is on, so the
    episode is no success; `cmcl.envs.metrics.success`); unmatched_idle_share: of those worlds, the share with an
    agent on no landmark (the others: the spare agent shares a landmark). None in summaries written before they were
    measured (2026-12-06).
    """

    worlds: int
    missed_share: float
    missed_by_class: dict[str, float]
    agent_idle_share: list[float]
    agent_crowding_share: list[float]
    agent_wall_share: list[float]
    idle_distance_median: float
    covered_unmatched_share: float | None = None
    unmatched_idle_share: float | None = None

    def lines(self) -> list[str]:
        """Human-readable summary, one statement per line."""
        pct = lambda x: f"{100 * x:.1f} %"  # noqa: E731
        out = [f"worlds with an uncovered landmark at the final step: {pct(self.missed_share)} of {self.worlds}"]
        if self.missed_share > 0:
            out.append("  of those: " + ", ".join(f"{name} {pct(self.missed_by_class[name])}"
                                                 for name in MISS_CLASSES)
                       + f" (median distance from an idle agent to the nearest uncovered landmark "
                         f"{self.idle_distance_median:.3f})")
        if self.covered_unmatched_share is not None:
            out.append(f"worlds with every landmark covered, but not each by an agent of its own (one agent on two): "
                       f"{pct(self.covered_unmatched_share)} of {self.worlds}"
                       + (f"; of those, with an agent on no landmark {pct(self.unmatched_idle_share)}"
                          if self.covered_unmatched_share > 0 else ""))
        for label, shares in (("on no landmark", self.agent_idle_share),
                              ("sharing its landmark", self.agent_crowding_share),
                              ("at a wall", self.agent_wall_share)):
            out.append(f"  agents {label}: " + ", ".join(f"{i}: {pct(s)}" for i, s in enumerate(shares)))
        return out


def miss_anatomy(positions: np.ndarray, landmarks: np.ndarray, cover_radius: float,
                 agent_radius: float) -> MissAnatomy:
    """The MissAnatomy of the final step. positions: float[B, N, 2] agents, landmarks: float[B, L, 2] (world units,
    as `BatchedWorld.get_state()` returns them); cover_radius: the task's cover threshold (ALGORITHM.md §6.1)."""
    pos = np.asarray(positions, dtype=np.float64)
    lms = np.asarray(landmarks, dtype=np.float64)
    if pos.ndim != 3 or lms.ndim != 3 or pos.shape[0] != lms.shape[0] or pos.shape[2] != 2 or lms.shape[2] != 2:
        raise ValueError(f"positions must be [B, N, 2] and landmarks [B, L, 2] with one B, got {pos.shape} "
                         f"and {lms.shape}")
    b = pos.shape[0]
    dist = np.sqrt(np.square(lms[:, None] - pos[:, :, None]).sum(-1))  # [B, N, L]
    cover = dist < cover_radius
    others_on = cover.sum(axis=1, keepdims=True) - cover  # [B, N, L]: other agents on landmark l
    on_any = cover.any(axis=2)  # [B, N]
    alone_somewhere = (cover & (others_on == 0)).any(axis=2)
    crowding = on_any & ~alone_somewhere
    idle = ~on_any
    uncovered = ~cover.any(axis=1)  # [B, L]
    missed = uncovered.any(axis=1)  # [B]
    far = np.where(uncovered[:, None, :], dist, np.inf).min(axis=2)  # [B, N]: to the nearest uncovered landmark
    near_idle = (idle & (far <= NEAR_RADII * cover_radius)).any(axis=1)
    crowded_world = crowding.any(axis=1)
    classes = {"crowded": missed & crowded_world, "short": missed & ~crowded_world & near_idle,
               "far": missed & ~crowded_world & ~near_idle}
    n_missed = int(missed.sum())
    wall = (np.abs(pos) >= ARENA_HALF - agent_radius - WALL_TOLERANCE).any(axis=2)
    unmatched = ~missed & ~success(cover)
    n_unmatched = int(unmatched.sum())
    idle_far = far[idle & missed[:, None]]
    return MissAnatomy(
        worlds=b,
        missed_share=n_missed / b if b else 0.0,
        missed_by_class={k: (float(v.sum()) / n_missed if n_missed else 0.0) for k, v in classes.items()},
        agent_idle_share=idle.mean(axis=0).tolist(),
        agent_crowding_share=crowding.mean(axis=0).tolist(),
        agent_wall_share=wall.mean(axis=0).tolist(),
        idle_distance_median=float(np.median(idle_far)) if idle_far.size else float("nan"),
        covered_unmatched_share=n_unmatched / b if b else 0.0,
        unmatched_idle_share=float((unmatched & idle.any(axis=1)).sum()) / n_unmatched if n_unmatched else 0.0,
    )


def on_plateau(coverage: np.ndarray, low: float = 0.65, high: float = 0.85, window: int = 100) -> np.ndarray:
    """bool[E]: the episodes whose `window`-episode moving average of coverage lies in [low, high] (at N = 4 the band
    around three landmarks of four). coverage: float[E], the final-step coverage of each training episode in order."""
    if not 0 <= low < high <= 1:
        raise ValueError(f"need 0 <= low < high <= 1, got low={low}, high={high}")
    ma = moving_average(coverage, window)
    return (ma >= low) & (ma <= high)


def plateau_episodes(coverage: np.ndarray, low: float = 0.65, high: float = 0.85, window: int = 100) -> int:
    """How many episodes are `on_plateau`."""
    return int(on_plateau(coverage, low, high, window).sum())
