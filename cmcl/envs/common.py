"""Shared constants and argument checks for the sparse MPE tasks (ALGORITHM.md §6).

The tasks' world parameters are `cmcl.envs.params` (SpreadParams, TagParams); their initial states are sampled by
`cmcl.envs.spawn`.

Where it sits: imported by both implementations of each task, the PettingZoo reference
(`sparse_spread_v0`, `sparse_tag_v0`, built on mpe2's World) and the batched numpy twins
(`cmcl.envs.batched`).

Units: positions in arena units (the arena is the square [-0.5, 0.5]^2), velocities per unit time,
time step dt = 0.1.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

# MPE physics, kept unchanged [V mpe2 _mpe_utils/core.py].
DT = 0.1
DAMPING = 0.25
CONTACT_FORCE = 100.0
CONTACT_MARGIN = 1e-3
MASS = 1.0
ARENA_HALF = 0.5  # walls at x = +-0.5 and y = +-0.5 (side 1)



def check_int(name: str, value: object, minimum: int) -> int:
    """Return `value` as int or raise ValueError naming the argument (bools and non-integers are refused)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} {IntAtLeast(minimum).why}, got {value}")
    return int(value)


def check_float(name: str, value: object, low: float = 0.0, high: float = math.inf, low_open: bool = True) -> float:
    """Return `value` as a finite float in (low, high) (or [low, high) if not low_open) or raise ValueError."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"{name} must be a number, got {value!r}")
    v = float(value)
    bad_low = v <= low if low_open else v < low
    if not math.isfinite(v) or bad_low or v >= high:
        raise ValueError(f"{name} {FloatIn(low, high, low_open).why}, got {value!r}")
    return v


@dataclass(frozen=True)
class IntAtLeast:
    """The range rule of an integer world parameter (cmcl.field_docs): `check_int(name, value, minimum)`."""

    minimum: int

    @property
    def why(self) -> str:
        return f"must be >= {self.minimum}"

    def check(self, name: str, value: object) -> None:
        check_int(name, value, self.minimum)


@dataclass(frozen=True)
class FloatIn:
    """The range rule of a real world parameter (cmcl.field_docs): `check_float(name, value, low, high,
    low_open)`."""

    low: float = 0.0
    high: float = math.inf
    low_open: bool = True

    @property
    def why(self) -> str:
        return f"must be a finite number in {'(' if self.low_open else '['}{self.low}, {self.high})"

    def check(self, name: str, value: object) -> None:
        check_float(name, value, self.low, self.high, self.low_open)


def check_dtype(dtype: object) -> np.dtype:
    """The twins compute in float32 (default, fast) or float64 (parity with mpe2's float64 physics)."""
    dt = np.dtype(dtype)  # type: ignore[arg-type]
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be float32 or float64, got {dtype!r}")
    return dt


def make_rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    """A Generator from an int seed, a SeedSequence, an existing Generator (used as is) or None (fresh entropy)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer | np.random.SeedSequence)):
        raise ValueError(f"seed must be an int, a SeedSequence, a Generator or None, got {seed!r}")
    return np.random.default_rng(seed)


def check_state_arrays(state: dict[str, Any], shapes: dict[str, tuple[int, ...]],
                       accumulators: Iterable[str]) -> dict[str, np.ndarray]:
    """The world-state arrays of `state` (keys of `shapes`), each checked for presence, shape and finiteness.

    Keys other than those of `shapes` and the optional episode `accumulators` are refused (a state of the other
    task). Raises ValueError naming the key; nothing is loaded by this function.
    """
    arrays = {}
    for key, shape in shapes.items():
        if key not in state:
            raise ValueError(f"state is missing {key!r}")
        arr = np.asarray(state[key])
        if arr.shape != shape:
            raise ValueError(f"state[{key!r}] must have shape {shape}, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"state[{key!r}] must be finite")
        arrays[key] = arr
    unknown = set(state) - set(shapes) - set(accumulators)
    if unknown:
        raise ValueError(f"state has unknown keys {sorted(unknown)} (wrong task?)")
    return arrays
