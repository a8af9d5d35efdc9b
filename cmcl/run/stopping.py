"""A graceful stop on SIGINT or SIGTERM, for both runners; a second signal forces the exit.

Where it sits: both runners' commands (`python -m cmcl train | resume`; services/launch.py) install a `StopSignals`
around training. The first SIGINT (Ctrl-C) or SIGTERM (`docker stop`, Kubernetes, `kill`) only sets `requested`; the
training loop polls it between steps, stops issuing work, drains, checkpoints and returns, and the CLI exits with
`exit_code` (130 for SIGINT, 143 for SIGTERM: 128 + the signal number, the shell's convention). A second signal while
that is under way calls `force` (default: exit at once with the same code, no checkpoint). `exit_without_teardown` is
how every training and evaluation command ends.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from types import FrameType
from typing import Any, NoReturn

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _exit_now(signum: int) -> None:
    print(f"\n{signal.Signals(signum).name}: exiting now", file=sys.stderr, flush=True)
    os._exit(128 + signum)


class StopSignals:
    """Install with `with StopSignals() as stop:`; the previous handlers come back on exit.

    requested: whether a stop signal has arrived; signum: the first one (None before); exit_code: 128 + signum.
    """

    def __init__(self, force: Callable[[int], None] = _exit_now, notice: Callable[[str], None] | None = None):
        self.signum: int | None = None
        self._force, self._notice = force, notice
        self._previous: dict[int, Any] = {}
        self._over = False

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""

    @property
    def exit_code(self) -> int:
        return 0 if self.signum is None else 128 + self.signum

    def training_over(self) -> None:
        """Nothing is left to save: from now on the first signal exits at once (through `force`)."""
        self._over = True

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None or self._over:
            self._force(signum)
            return
        self.signum = signum
        if self._notice is not None:
            self._notice(f"{signal.Signals(signum).name} received: stopping after a final checkpoint "
                         f"(send it again to exit at once)")

    def install(self) -> StopSignals:
        """Handle SIGINT and SIGTERM from now on (idempotent); the handlers found are kept for `restore`."""
        for sig in STOP_SIGNALS:
            if sig not in self._previous:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def restore(self) -> None:
        """Put back the handlers `install` found."""
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def __enter__(self) -> StopSignals:
        return self.install()

    def __exit__(self, *exc: object) -> None:
        self.restore()


def exit_without_teardown(code: int | None) -> NoReturn:
    """End a command with exit status `code` (None: 0, as `sys.exit`) at once, without the interpreter's teardown
    of its modules: with torch, Ray and matplotlib loaded that teardown took 1-2.5 s on a 2-core machine after every
    run (measured), before the prompt came back. For a command's last step only: stdout and stderr are flushed here,
    every file a run writes is closed by the time its function returns, and atexit handlers do not run (Ray's, the
    one registered, has nothing left to do once the launcher has stopped Ray). An exception still ends the command
    the ordinary way."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code or 0)
