"""A run directory on a disk that fills up (cmcl.io.write_failure): the command ends in one line naming the file it
could not write and what a resume starts from, exit 2; nothing written before changes; once there is room, the
resume goes on from there. Before (found 2026-12-06 on a 1.5 MB tmpfs): the inline runner ended in a traceback, the
service in "error: [Errno 28] No space left on device" naming no file, `evaluate` in a matplotlib traceback.

The disk is a real tmpfs, mounted in a private mount namespace (`unshare -m`, as root) over an empty folder of the
test's, and filled with a file of zeros; the commands run inside that namespace, their output goes to the test's
own folder outside it. Skipped where no private mount namespace can be made.
"""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tests.tiny import tiny_overrides

ROOT = Path(__file__).resolve().parents[1]
NO_ROOM = "No space left on device"


def in_namespace(script: str, tmp_path: Path, timeout: float = 300) -> None:
    """Run the shell `script` with a 64 MB tmpfs mounted at $DISK (tmp_path/disk) in a private mount namespace, the
    commands' `$CMCL` (`python -m cmcl`) and a `fill` function that leaves the tmpfs with `$1` KiB free."""
    if subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode != 0:
        pytest.skip("no private mount namespace here (unshare -m)")
    disk = tmp_path / "disk"
    disk.mkdir()
    prelude = (f"set -u; DISK={shlex.quote(str(disk))}; CMCL='{shlex.quote(sys.executable)} -m cmcl'; "
               "mount -t tmpfs -o size=64m tmpfs $DISK || exit 99; "
               "fill() { dd if=/dev/zero of=$DISK/room bs=1k count=$1 2>/dev/null; "
               "dd if=/dev/zero of=$DISK/filler bs=1M 2>/dev/null; dd if=/dev/zero of=$DISK/filler2 bs=4k 2>/dev/null; "
               "rm $DISK/room; }; ")
    done = subprocess.run(["unshare", "-m", "sh", "-c", prelude + script], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)
    assert done.returncode == 0, done.stdout + done.stderr


def one_error_line(stderr: str) -> str:
    """The only stderr line starting 'error: ' (Ray's own log lines aside), and no traceback."""
    assert "Traceback" not in stderr, stderr
    errors = [line for line in stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, stderr
    return errors[0]


def test_an_inline_run_on_a_full_disk_ends_in_one_line_keeps_its_checkpoints_and_resumes_once_there_is_room(
        tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    tiny = " ".join(f"--set {shlex.quote(s)}" for s in tiny_overrides())
    o = shlex.quote(str(out))
    in_namespace(
        f"$CMCL train --runner inline {tiny} --set run.dir=$DISK/r --set run.episodes=16 "
        f"--quiet --no-eval > {o}/first.out 2>&1 || exit 98; "
        f"find $DISK/r/checkpoints -type f -exec sha256sum {{}} + > {o}/before.sha; fill 0; "
        f"$CMCL resume $DISK/r --more-episodes 16 --quiet --no-eval > {o}/full.out 2> {o}/full.err; "
        f"echo $? > {o}/full.rc; sha256sum -c --quiet {o}/before.sha > {o}/kept.txt 2>&1; echo $? > {o}/kept.rc; "
        f"$CMCL evaluate $DISK/r --episodes 4 > {o}/eval.out 2> {o}/eval.err; echo $? > {o}/eval.rc; "
        f"rm $DISK/filler $DISK/filler2; "
        f"$CMCL resume $DISK/r --more-episodes 16 --quiet --no-eval > {o}/room.out 2>&1; echo $? > {o}/room.rc",
        tmp_path)
    run = tmp_path / "disk" / "r"
    line = one_error_line((out / "full.err").read_text())
    assert (out / "full.rc").read_text().strip() == "2", line
    assert line.startswith(f"error: cannot write {run}/") and NO_ROOM in line, line
    assert "the run keeps its last checkpoint; make room, then resume with: " in line, line
    assert line.endswith(f"cmcl resume {run}"), line
    assert (out / "kept.rc").read_text().strip() == "0", (out / "kept.txt").read_text()  # every checkpoint as it was
    evaluated = (out / "eval.out").read_text()
    assert (out / "eval.rc").read_text().strip() == "0" and "Traceback" not in (out / "eval.err").read_text()
    assert f"gif: not written (cannot write {run}/eval.gif: {NO_ROOM})" in evaluated, evaluated
    assert f"learning curve: not written (cannot write {run}/learning_curve.png: {NO_ROOM})" in evaluated, evaluated
    resumed = (out / "room.out").read_text()
    assert (out / "room.rc").read_text().strip() == "0", resumed
    assert f"resuming {run} from checkpoints/service/learner-000001.pt" in resumed and "done: 32 episodes" in resumed, \
        resumed


def test_a_service_run_on_a_full_disk_ends_in_one_line_and_resumes_once_there_is_room(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    tiny = " ".join(f"--set {shlex.quote(s)}" for s in tiny_overrides(service=True))
    o = shlex.quote(str(out))
    in_namespace(
        f"fill 256; $CMCL train --runner service {tiny} --set run.dir=$DISK/r --set run.episodes=400 --quiet "
        f"--no-eval > {o}/full.out 2> {o}/full.err; echo $? > {o}/full.rc; rm $DISK/filler $DISK/filler2; "
        f"$CMCL resume $DISK/r --quiet --no-eval > {o}/room.out 2>&1; echo $? > {o}/room.rc", tmp_path)
    run = tmp_path / "disk" / "r"
    line = one_error_line((out / "full.err").read_text())
    assert (out / "full.rc").read_text().strip() == "2", line
    assert line.startswith(f"error: cannot write {run}/") and NO_ROOM in line, line
    assert "make room, then resume with: " in line and line.endswith(f"cmcl resume {run}"), line
    resumed = (out / "room.out").read_text()
    assert (out / "room.rc").read_text().strip() == "0" and "done: " in resumed, resumed
