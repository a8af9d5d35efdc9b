"""The inline runner: Algorithm 1 in one process without Ray (`inline.py`), and its command line (`__main__.py`,
`python -m cmcl train --runner inline`, alias `python -m cmcl.loop`)."""

from cmcl.loop.inline import RNG_NAMES, InlineLoop, replay_snapshot_path

__all__ = ["RNG_NAMES", "InlineLoop", "replay_snapshot_path"]
