"""The main job's stop and resume paths, as a user meets them, with the numbers: per scenario the exit code, what
is on disk, the training coverage before the stop and after the resume, and the processes left behind.

One service run (`configs/spread_cmcl.toml`, the README's command) goes through a chain: trained for `--train`
seconds, then Ctrl-C (SIGINT to its process group, as a terminal sends it); resumed and, after `--train` seconds,
SIGTERM; resumed and, after `--train` seconds, SIGKILL of the launcher alone; resumed once more for `--train`
seconds and stopped with SIGINT. Coverage "before" is the mean final-step coverage of the last 100 episodes in
metrics.jsonl when the stop came; "after" that of the first 100 episodes the resumed run logged (the random
policy's is about 0.095, bench/README or lab/RESULTS.md).

    python bench/stop_resume.py [--train 90] [--out runs/bench_stop_resume]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cmcl.run.rundir import RunDirectory  # noqa: E402
from services.runtime.reaper import descendants, process_table  # noqa: E402

WINDOW = 100


def coverage_rows(run_dir: Path) -> list[float]:
    return [r["coverage"] for r in RunDirectory.open(run_dir).rows("episode")]


def run_until(args: list[str], seconds: float, stop: signal.Signals) -> tuple[int, dict[int, int], str]:
    """Start `args` in its own process group, let it train `seconds` (counted from its first progress line), send
    `stop` (SIGKILL: to the launcher alone; else to the group); (exit code, processes seen below it, output)."""
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    seen: dict[int, int] = {}
    lines, started = [], None
    for line in proc.stdout:
        lines.append(line)
        seen.update(descendants({proc.pid}, process_table()))
        started = started or (time.monotonic() if line.startswith("ep ") else None)
        if started and time.monotonic() - started >= seconds:
            break
    if stop == signal.SIGKILL:
        proc.kill()
    else:
        os.killpg(proc.pid, stop)
    lines += proc.stdout.readlines()
    proc.wait()
    return proc.returncode, seen, "".join(lines)


def left_alive(seen: dict[int, int], timeout: float = 60) -> list[str]:
    """Processes of `seen` still running once the reaper has had `timeout` seconds (polled)."""
    deadline = time.monotonic() + timeout
    while True:
        table = process_table()
        alive = [pid for pid, start in seen.items() if table.get(pid, (0, -1))[1] == start]
        if not alive or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    return [Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")[:60] for pid in alive]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--train", type=float, default=90.0, help="training seconds before each stop")
    parser.add_argument("--out", default="runs/bench_stop_resume")
    args = parser.parse_args()
    run_dir = Path(args.out)
    shutil.rmtree(run_dir, ignore_errors=True)
    start = [sys.executable, "-m", "services.launch", "--config", "configs/spread_cmcl.toml", "--set",
             f"run.dir={run_dir}", "--metrics-port", "0"]
    resume = [sys.executable, "-m", "services.launch", "--resume", str(run_dir), "--metrics-port", "0"]
    chain = [("start, then Ctrl-C", start, signal.SIGINT), ("resume, then SIGTERM", resume, signal.SIGTERM),
             ("resume, then SIGKILL of the launcher", resume, signal.SIGKILL),
             ("resume, then Ctrl-C", resume, signal.SIGINT)]
    print("| scenario | exit | checkpoints on disk after | coverage: last 100 before the stop | first 100 of the "
          "resumed run | processes left |")
    print("| --- | --- | --- | --- | --- | --- |")
    previous_tail = None
    for name, command, stop in chain:
        counters = RunDirectory(run_dir).supervisor_counters
        # a resume drops the rows logged after the last checkpoint, then appends its own from there
        before_rows = json.loads(counters.read_text())["episodes_logged"] if counters.exists() else 0
        code, seen, output = run_until(command, args.train, stop)
        left = left_alive(seen)
        rows = coverage_rows(run_dir)
        resumed_head = rows[before_rows:before_rows + WINDOW] if previous_tail is not None else []
        service = RunDirectory(run_dir).service_dir
        files = sorted(p.name for p in service.glob("*.manifest.json"))
        tail = rows[-WINDOW:]
        print(f"| {name} | {code} | {', '.join(f.split('.')[0] for f in files)} | "
              f"{sum(tail) / max(len(tail), 1):.3f} (to episode {len(rows)}) | "
              + (f"{sum(resumed_head) / len(resumed_head):.3f} (previous stop's last 100: {previous_tail:.3f})"
                 if resumed_head else "-") + f" | {len(left)} {left if left else ''} |", flush=True)
        if "Traceback" in output:
            print(output[-2000:])
        previous_tail = sum(tail) / max(len(tail), 1)
    print(json.dumps(json.loads((run_dir / "summary.json").read_text()).get("checkpoint_seconds", [])))


if __name__ == "__main__":
    main()
