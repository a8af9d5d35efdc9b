"""The batched numpy twins of `env.factory` environments: which factory path has one and how to build it.

Where it sits: `cmcl.system.make_batched_env` asks `twin_for` when `env.twin = true`; the rollout worker, the
inline loop and the evaluation then step the twin (one vectorised world batch) instead of `env.num_envs` copies of
the ParallelEnv (`cmcl.envs.parallel_vector`). A twin reproduces its ParallelEnv on the same seed and actions
(tests/test_sparse_tasks.py: observations, rewards, dones and the episodes' success and coverage).

Registered: the sparse navigation worlds (`cmcl.envs.sparse_nav_v0:parallel_env` -> `cmcl.envs.sparse_nav.
BatchedSparseNav`, VACL's and SPMARL's variants). The grids (Push-Box, Pass) have none.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from cmcl.envs.world_settings import NAV_FACTORY


def _nav_twin(kwargs: Mapping[str, Any], num_envs: int, episode_length: int, seed: Any, auto_reset: bool) -> Any:
    """BatchedSparseNav of the variant `kwargs` names (the ParallelEnv's own keywords), `episode_length` steps."""
    from cmcl.envs.sparse_nav import BatchedSparseNav, variant

    fields = {k: v for k, v in kwargs.items() if k not in ("variant", "render_mode", "max_cycles")}
    params = variant(kwargs.get("variant", "vacl"), **{**fields, "episode_length": int(episode_length)})
    return BatchedSparseNav(num_envs, params, seed=seed, auto_reset=auto_reset, dtype=np.float32)


TWINS: dict[str, Callable[..., Any]] = {NAV_FACTORY: _nav_twin}


def twin_for(factory: str) -> Callable[..., Any]:
    """The twin builder (kwargs, num_envs, episode_length, seed, auto_reset) of `factory`, else ValueError naming it
    and the factories that have one."""
    if factory not in TWINS:
        raise ValueError(f"env.twin = true: env.factory {factory!r} has no batched twin (factories that have one: "
                         f"{sorted(TWINS)})")
    return TWINS[factory]
