"""Policy weights as plain numpy dicts: what the learner publishes and what actors load, with a version.

Where it sits: the learner publishes `published_weights(maddpg)` once per version (the service puts it in the
object store); rollout workers load the online actors, teachers and the ICM-free scorers load the target
actor and target critic they need for TD targets (ALGORITHM.md §3.2, A2). Numpy only crosses the boundary.
`maddpg` is any learner holding the parts as torch modules under those attribute names (cmcl.learners.maddpg.MADDPG);
this module does not import it, so the learner can use the loader.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

PARTS = ("actor", "target_actor", "target_critic")


def published_weights(maddpg: object) -> dict[str, dict[str, np.ndarray]]:
    """{"actor": online actor, "target_actor": ..., "target_critic": ...}, each {param name: float32 array}."""
    return {part: {k: v.detach().numpy().copy() for k, v in getattr(maddpg, part).state_dict().items()}
            for part in PARTS}


def load_published(maddpg: object, weights: Mapping[str, Mapping[str, np.ndarray]],
                   parts: tuple[str, ...] = PARTS) -> None:
    """Load the given parts of `published_weights` output into `maddpg` (shapes and finiteness checked first)."""
    staged = {}
    for part in parts:
        module = getattr(maddpg, part)
        own = module.state_dict()
        given = weights[part]
        if set(given) != set(own):
            raise ValueError(f"{part} weight keys {sorted(given)} differ from the expected {sorted(own)}")
        tensors = {}
        for key, value in given.items():
            arr = np.asarray(value, dtype=np.float32)
            if arr.shape != tuple(own[key].shape) or not np.isfinite(arr).all():
                raise ValueError(f"{part}.{key} must be finite with shape {tuple(own[key].shape)}, got {arr.shape}")
            tensors[key] = torch.from_numpy(arr.copy())
        staged[part] = tensors
    for part, tensors in staged.items():
        getattr(maddpg, part).load_state_dict(tensors)
