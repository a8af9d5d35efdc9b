"""Calibration of the sparse predator-prey world (ALGORITHM.md §6.2, row "calibration").

Requirement: with uniformly random policies on both sides (actions uniform in [-1, 1]^2) the predators
must win 0.3-0.6 of rounds (target ~0.45). A round is one 30-step episode; the predators win it iff at
least one (predator, prey) pair is in contact (distance < r_pred + r_prey) at some step
(`cmcl.envs.metrics.predator_win`). Each candidate is a set of `BatchedSparseTag` parameters given
relative to §6.2's original recommendation (4 predators, 2 prey, radii 0.075 / 0.05, 3 obstacles of
radius 0.1 centred in [-0.3, 0.3]^2, predator accel 3 / max speed 1, prey accel 4 / max speed 2);
the prey's max speed is always twice the predators'.

For every candidate the script measures, with the batched twin (B worlds at once, fixed seeds):
  * the random-vs-random predator win rate over `--rounds` rounds, with a Wilson 95% interval;
  * the win rate of a scripted chaser (every predator pushes at full force towards the nearest prey,
    read from its own observation) against random prey, over `--chase-rounds` rounds: a world where
    this trivial policy does not clearly beat random predators would leave nothing to learn.
It prints a markdown table, then the measurement of the current defaults (`TagParams()`), and as its
last line `chosen: ...`: among candidates with >= 2 prey whose 95% interval lies inside [0.3, 0.6],
those with the fewest departures from the recommendation (counted per group: team sizes, radii,
obstacles, speeds), then the one closest to 0.45.

    python lab/studies/tag_calibration.py [--rounds 4000] [--chase-rounds 2000] [--batch 1000] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from cmcl.envs.batched import BatchedSparseTag  # noqa: E402
from cmcl.envs.params import TagParams  # noqa: E402

BAND = (0.3, 0.6)
TARGET = 0.45
# ALGORITHM.md §6.2's original recommendation, before calibration (explicit: independent of the defaults).
REFERENCE = TagParams(num_predators=4, num_prey=2, num_obstacles=3, predator_radius=0.075, prey_radius=0.05,
                      obstacle_radius=0.1, predator_accel=3.0, predator_max_speed=1.0, prey_accel=4.0,
                      prey_max_speed=2.0, obstacle_spawn=0.3)
GROUPS = {
    "teams": ("num_predators", "num_prey"),
    "radii": ("predator_radius", "prey_radius"),
    "obstacles": ("num_obstacles", "obstacle_radius", "obstacle_spawn"),
    "speeds": ("predator_accel", "predator_max_speed", "prey_accel", "prey_max_speed"),
}
SLOW = {"predator_accel": 2.0, "predator_max_speed": 0.5, "prey_max_speed": 1.0}  # prey still twice as fast
HALF = {"predator_radius": 0.0375, "prey_radius": 0.025}  # MPE's absolute sizes x 0.5 (ratio 3:2 kept)
FIFTHS = {"predator_radius": 0.03, "prey_radius": 0.02}  # MPE's absolute sizes x 0.4
# (label, overrides of REFERENCE)
CANDIDATES: list[tuple[str, dict]] = [
    ("4v2 (§6.2 recommendation)", {}),
    ("4v2, obstacles r=0.15", {"obstacle_radius": 0.15}),
    ("4v2, obstacles r=0.2", {"obstacle_radius": 0.2}),
    ("4v2, obstacles in [-0.4,0.4]^2", {"obstacle_spawn": 0.4}),
    ("4v2, slow (pred 2/0.5, prey 4/1)", SLOW),
    ("4v2, radii x0.5", HALF),
    ("4v2, radii x0.4", FIFTHS),
    ("3v2", {"num_predators": 3}),
    ("3v2, radii x0.5", {"num_predators": 3, **HALF}),
    ("3v2, radii x0.4", {"num_predators": 3, **FIFTHS}),
    ("2v2", {"num_predators": 2}),
    ("2v2, obstacles r=0.2", {"num_predators": 2, "obstacle_radius": 0.2}),
    ("2v2, slow (pred 2/0.5, prey 4/1)", {"num_predators": 2, **SLOW}),
    ("2v2, radii 0.05/0.05", {"num_predators": 2, "predator_radius": 0.05}),
    ("2v2, radii 0.05/0.025", {"num_predators": 2, "predator_radius": 0.05, "prey_radius": 0.025}),
    ("2v2, radii x0.6", {"num_predators": 2, "predator_radius": 0.045, "prey_radius": 0.03}),
    ("2v2, radii x0.5", {"num_predators": 2, **HALF}),
    ("2v2, radii x0.5, obstacles r=0.15", {"num_predators": 2, **HALF, "obstacle_radius": 0.15}),
    ("2v2, radii x0.5, obstacles r=0.2", {"num_predators": 2, **HALF, "obstacle_radius": 0.2}),
    ("2v2, radii x0.4", {"num_predators": 2, **FIFTHS}),
    ("3v1 (MPE simple_tag teams)", {"num_predators": 3, "num_prey": 1}),
    ("3v1, radii x0.5", {"num_predators": 3, "num_prey": 1, **HALF}),
    ("2v1", {"num_predators": 2, "num_prey": 1}),
    ("2v1, obstacles r=0.15", {"num_predators": 2, "num_prey": 1, "obstacle_radius": 0.15}),
]


def wilson(wins: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score 95% interval of a binomial proportion wins / n."""
    p = wins / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def chase_actions(obs: np.ndarray, p: TagParams) -> np.ndarray:
    """float64[B, m, 2]: unit pushes of each predator towards its nearest prey, from obs [B, N, obs_dim].

    A predator's observation holds pos_j - pos_i for the other agents in index order from offset
    4 + 2O; prey are the last n of those N - 1 entries.
    """
    m, q, o = p.num_predators, p.num_prey, p.num_obstacles
    start = 4 + 2 * o + 2 * (m - 1)
    rel = obs[:, :m, start : start + 2 * q].astype(np.float64).reshape(len(obs), m, q, 2)
    nearest = np.linalg.norm(rel, axis=-1).argmin(axis=-1)  # [B, m]
    target = np.take_along_axis(rel, nearest[..., None, None], axis=2)[:, :, 0]  # [B, m, 2]
    return target / np.maximum(np.linalg.norm(target, axis=-1, keepdims=True), 1e-9)


def win_rate(p: TagParams, rounds: int, batch: int, seed: int, chase: bool = False) -> tuple[int, int]:
    """(predator wins, rounds played): ceil(rounds / batch) batches of `batch` 30-step episodes."""
    env = BatchedSparseTag(batch, p, seed=seed)
    rng = np.random.default_rng(seed + 1)
    wins = played = 0
    for _ in range(math.ceil(rounds / batch)):
        obs = env.reset()
        done = np.zeros(batch, dtype=bool)
        while not done.all():
            actions = rng.uniform(-1.0, 1.0, (batch, p.num_agents, 2))
            if chase:
                actions[:, : p.num_predators] = chase_actions(obs, p)
            obs, _, done, info = env.step(actions)
        wins += int(info["episode"]["predator_win"].sum())
        played += batch
    return wins, played


def departures(p: TagParams) -> list[str]:
    """The groups of GROUPS in which p differs from REFERENCE."""
    return [g for g, names in GROUPS.items() if any(getattr(p, k) != getattr(REFERENCE, k) for k in names)]


def describe(p: TagParams) -> str:
    return (f"{p.num_predators}v{p.num_prey}, predator_radius={p.predator_radius}, prey_radius={p.prey_radius}, "
            f"{p.num_obstacles} obstacles radius={p.obstacle_radius} spawn={p.obstacle_spawn}, "
            f"predator accel/max speed={p.predator_accel}/{p.predator_max_speed}, "
            f"prey={p.prey_accel}/{p.prey_max_speed}")


def fmt(wins: int, n: int) -> str:
    lo, hi = wilson(wins, n)
    return f"{wins / n:.3f} ± {(hi - lo) / 2:.3f} [{lo:.3f}, {hi:.3f}]"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=4000, help="random-vs-random rounds per candidate")
    parser.add_argument("--chase-rounds", type=int, default=2000, help="chaser-vs-random rounds per candidate")
    parser.add_argument("--batch", type=int, default=1000, help="worlds stepped at once")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    for name in ("rounds", "chase_rounds", "batch"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")

    print(f"random vs random: {args.rounds} rounds per candidate; scripted chaser vs random prey: "
          f"{args.chase_rounds}; 30-step rounds, B = {args.batch}, seed {args.seed}; Wilson 95% intervals")
    print()
    print("| candidate | m v n | r_pred / r_prey | obstacle r / spawn | pred accel / vmax | prey accel / vmax "
          "| random win rate | chaser win rate | in 0.3-0.6 |")
    print("|---|---|---|---|---|---|---|---|---|")
    eligible = []
    for label, overrides in CANDIDATES:
        p = replace(REFERENCE, **overrides)  # validated by TagParams itself
        w, n = win_rate(p, args.rounds, args.batch, args.seed)
        cw, cn = win_rate(p, args.chase_rounds, args.batch, args.seed, chase=True)
        lo, hi = wilson(w, n)
        inside = BAND[0] <= lo and hi <= BAND[1]
        print(f"| {label} | {p.num_predators}v{p.num_prey} | {p.predator_radius} / {p.prey_radius} "
              f"| {p.obstacle_radius} / {p.obstacle_spawn} | {p.predator_accel} / {p.predator_max_speed} "
              f"| {p.prey_accel} / {p.prey_max_speed} | {fmt(w, n)} | {fmt(cw, cn)} | {'yes' if inside else 'no'} |",
              flush=True)
        if inside and p.num_prey >= 2:
            eligible.append((len(departures(p)), abs(w / n - TARGET), label, p, (w, n), (cw, cn)))
    print()
    d = TagParams()
    w, n = win_rate(d, args.rounds, args.batch, args.seed)
    cw, cn = win_rate(d, args.chase_rounds, args.batch, args.seed, chase=True)
    print(f"current defaults (TagParams()): {describe(d)}: random {fmt(w, n)}, chaser {fmt(cw, cn)}")
    if not eligible:
        print("chosen: none (no candidate with >= 2 prey has its 95% interval inside [0.3, 0.6])")
        return 1
    _, _, label, p, (w, n), (cw, cn) = min(eligible, key=lambda e: e[:2])
    print(f"chosen: {label}: {describe(p)}; random win rate {fmt(w, n)}, chaser {fmt(cw, cn)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
