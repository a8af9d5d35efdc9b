"""The inline runner: Algorithm 1 in one process without Ray (`inline.py`; what its checkpoint holds, `checkpoint.py`;
the metrics rows it logs, `metrics_rows.py`), and its command line (`__main__.py`, `python -m cmcl train --runner
inline`, alias `python -m cmcl.loop`).

`from cmcl.loop import InlineLoop` works as before, but the names are loaded on first use (PEP 562): the command line
imports this package, and it takes the run directory's lock before it loads torch (a run in use is refused at once).
"""

from typing import Any

__all__ = ["RNG_NAMES", "InlineLoop"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from cmcl.loop import inline

        return getattr(inline, name)
    raise AttributeError(f"module 'cmcl.loop' has no attribute {name!r}")
