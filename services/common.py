"""Small pieces every service shell shares: config transport, incarnation ids, torch thread limits.

Where it sits: imported by the role shells in services/ (never by cmcl/). Configs cross process boundaries as
plain dicts (`Config.to_dict()`) and are re-validated on arrival.
"""

from __future__ import annotations

import os
import uuid
from typing import Any

from cmcl.config import Config, config_from_dict
from cmcl.io.rundir import load_checkpoint, save_torch_atomic


def actor_setup(config: Config | dict[str, Any], uses_torch: bool = True) -> Config:
    """Validate the config and limit torch (and BLAS) to one thread, as every actor on 2 cores should.

    Roles that never run a network (replay server, continuous-action rollout workers) pass uses_torch=False
    and never load torch (~190 MB of private memory each).
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if uses_torch:
        import torch

        torch.set_num_threads(1)
    return config if isinstance(config, Config) else config_from_dict(config)


def new_incarnation() -> str:
    """A fresh id for this process's life of an actor (changes on every restart)."""
    return uuid.uuid4().hex[:12]


def save_state(path: str | None, state: dict[str, Any]) -> str | None:
    """torch.save `state` (plain state dicts) to `path` atomically; no-op without a path."""
    if path is None:
        return None
    save_torch_atomic(path, state)
    return path


def load_state(path: str | None) -> dict[str, Any] | None:
    """The state saved by `save_state`, or None when there is none (torch.load with weights_only=True)."""
    if path is None or not os.path.exists(path):
        return None
    return load_checkpoint(path)
