"""The commands a message tells the user to type: this interpreter as it can be typed where the message is printed,
and the command that resumes a run directory.

Where it sits: the run directory (cmcl.run.rundir) names the resume command when it refuses to start over a run, and
the command-line layer (cmcl.run.flags, cmcl.__main__, both runners) when a run stops early or is refused; it imports
nothing of cmcl, so storage uses it without reaching up to the command line.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys


def python_command() -> str:
    """This interpreter as the user can type it: `python` when that is the one on PATH, else its path, relative to the
    working directory when below it (after `make run`, whose venv is not activated: `.venv/bin/python`)."""
    on_path = shutil.which("python")
    if on_path and os.path.abspath(on_path) == os.path.abspath(sys.executable):  # not resolved: a venv's python is a
        return "python"  # symlink to the base interpreter, a different environment
    relative = os.path.relpath(sys.executable)
    if relative.startswith(".."):
        return shlex.quote(os.path.abspath(sys.executable))
    return shlex.quote(relative if os.sep in relative else os.path.join(".", relative))  # a bare name means PATH


def resume_command(run_dir: object) -> str:
    """The command that resumes the run in `run_dir`, whichever runner wrote it (printed when a run stops early), as
    a shell line that works where it is printed."""
    return f"{python_command()} -m cmcl resume {shlex.quote(str(run_dir))}"
