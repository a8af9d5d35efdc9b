"""Small pieces every service shell shares: config transport, incarnation ids, torch thread limits.

Where it sits: imported by the role shells in services/ (never by cmcl/). Configs cross process boundaries as
plain dicts (`Config.to_dict()`) and are re-validated on arrival.
"""

from __future__ import annotations

import os
import uuid
from typing import Any

from cmcl.config import Config, config_from_dict
from cmcl.io.verified import VerifiedFile


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


def restarted_actor() -> bool:
    """Whether this process is a Ray actor that Ray has restarted (False in one process: `--runner inline`, where Ray
    is not even imported)."""
    import sys

    ray = sys.modules.get("ray")
    if ray is None or not ray.is_initialized():
        return False
    context = ray.get_runtime_context()
    return context.get_actor_id() is not None and context.was_current_actor_reconstructed


def new_incarnation() -> str:
    """A fresh id for this process's life of an actor (changes on every restart)."""
    return uuid.uuid4().hex[:12]


def save_state(path: str | None, state: dict[str, Any]) -> str | None:
    """torch.save `state` (plain state dicts) as the next checkpoint generation at `path` (`VerifiedFile`: file,
    then manifest with its SHA-256, the previous generation kept); no-op without a path. Returns the file."""
    if path is None:
        return None
    import io

    import torch

    buffer = io.BytesIO()
    torch.save(dict(state), buffer)
    return str(VerifiedFile(path).save(buffer.getvalue()))


def load_state(path: str | None) -> tuple[dict[str, Any] | None, list[str]]:
    """(the newest state saved by `save_state` that passes its manifest check, or None; the files refused on the
    way, "file: reason"). Checked before decoding; decoded with torch.load(weights_only=True). A refused file is
    reported on stderr and the previous generation is tried; with none usable the role starts fresh."""
    if path is None:
        return None, []
    import io
    import sys

    import torch

    loaded = VerifiedFile(path).load()
    refused = list(loaded.refused)
    state = None
    if loaded.payload is not None:
        try:
            state = torch.load(io.BytesIO(loaded.payload), map_location="cpu", weights_only=True)
        except Exception as err:  # noqa: BLE001 - a payload torch cannot decode is refused like a corrupt one
            refused.append(f"{path} generation {loaded.generation}: not a torch checkpoint ({type(err).__name__})")
    for reason in refused:
        print(f"checkpoint refused: {reason}", file=sys.stderr)
    return state, refused
