"""The two runners in one run: the in-process runner (`--runner inline`: the service's roles called in this
process, services.runtime.calls.InProcessCalls) against the Ray service (each role an actor), env-steps/s and learner
updates/s on the same config, same machine, same ratio, and the ratio of their update rates.

Both are the same supervisor loop: one update per `maddpg.update_every` world steps after the same warm-up (the
rate limiter holds the ratio, and the supervisor lets the learner catch up before it stops). Rates are steady-state,
from each run's metrics.jsonl (a progress row every 2 s on both runners): measured from the first progress row after
warm-up to the row where the last env step is counted, so the catch-up tail (updates only, no env steps) is left
out. The default 2000 episodes give a window of ~30-60 s on 2 cores at spread_cmcl's defaults; `--seconds S` ends
each run after S training seconds instead (run.max_seconds; a quick check of the bench), and a window shorter than
MIN_WINDOW_S is said so. Each runner's memory is the summed RSS / PSS of this process and every process it started
(the service's Ray processes), sampled while it trains.

    python bench/service_throughput.py [--config configs/spread_cmcl.toml] [--episodes 2000] [--seconds S]
                                       [--set k=v ...]
"""

from __future__ import annotations

import argparse
import shutil
import threading
import time
from pathlib import Path

import psutil

from cmcl.config import load_config
from cmcl.run.rundir import RunDirectory

DEFAULT_EPISODES = 2000
MIN_WINDOW_S = 20.0  # a shorter measured window is warm-up / catch-up dominated: main says so


def steady_rates(run: RunDirectory, while_collecting: bool = False) -> dict[str, float]:
    """Updates/s and env-steps/s between the first progress row with updates > 0 and the last row, or with
    `while_collecting` the first row that counts the run's last env step (the service's learner, teachers and ICM
    then only catch up: no env steps, and updates at a rate the rate limiter no longer holds)."""
    rows = [r for r in run.rows("progress") if "elapsed_s" in r]
    warm = [r for r in rows if r["updates"] > 0]
    if while_collecting and warm:
        final = rows[-1]["env_steps"]
        warm = warm[:next(i for i, r in enumerate(warm) if r["env_steps"] >= final) + 1]
    if len(warm) < 2:
        raise RuntimeError(f"{run.path}: too few progress rows after warm-up to measure a rate (raise --episodes)")
    first, last = warm[0], warm[-1]
    dt = last["elapsed_s"] - first["elapsed_s"]
    return {"updates_per_s": (last["updates"] - first["updates"]) / dt,
            "env_steps_per_s": (last["env_steps"] - first["env_steps"]) / dt, "seconds": dt,
            "updates": last["updates"], "env_steps": last["env_steps"]}


class MemorySampler:
    """Peak summed memory (bytes) of this process and all its descendants, sampled every second in a thread.

    Both RSS (counts shared library pages once per process, an over-estimate) and PSS (shared pages split
    between the processes that map them: the memory the service really takes) are tracked.
    """

    def __init__(self) -> None:
        self.peak_rss = self.peak_pss = self.processes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self) -> None:
        me = psutil.Process()
        while not self._stop.wait(1.0):
            rss = pss = 0
            procs = [me, *me.children(recursive=True)]
            for proc in procs:
                try:
                    info = proc.memory_full_info()
                except psutil.Error:
                    continue
                rss, pss = rss + info.rss, pss + getattr(info, "pss", info.rss)
            self.peak_rss, self.peak_pss = max(self.peak_rss, rss), max(self.peak_pss, pss)
            self.processes = max(self.processes, len(procs))

    def __enter__(self) -> MemorySampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def run_inline(config_path: str, overrides: list[str], out: Path) -> tuple[dict[str, float], MemorySampler]:
    """The in-process runner (`python -m cmcl train --runner inline`'s training) on `config_path`."""
    from services.launch import train_in_process

    config = load_config(config_path, [*overrides, f"run.dir={out}"])
    run = RunDirectory.create(out, config, overwrite=True)
    with MemorySampler() as memory:
        train_in_process(config, run)
    return steady_rates(run, while_collecting=True), memory


def run_service(config_path: str, overrides: list[str], out: Path) -> tuple[dict[str, float], MemorySampler]:
    """The Ray service (`python -m cmcl train --runner service`'s training, on an embedded Ray of every CPU)."""
    import ray

    from services.launch import run_service as launch

    config = load_config(config_path, [*overrides, f"run.dir={out}", "service.metrics_port=0"])
    run = RunDirectory.create(out, config, overwrite=True)
    ray.init(address="local", num_cpus=psutil.cpu_count(), include_dashboard=False, log_to_driver=False)
    try:
        with MemorySampler() as memory:
            launch(config, run, progress=None)
    finally:
        ray.shutdown()
    return steady_rates(run, while_collecting=True), memory


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", default="configs/spread_cmcl.toml")
    parser.add_argument("--episodes", type=int, default=DEFAULT_EPISODES,
                        help=f"episodes of each run (default {DEFAULT_EPISODES}: a steady-state window of 30-60 s)")
    parser.add_argument("--seconds", type=float, default=0.0,
                        help="end each run after this many training seconds (run.max_seconds; default 0: none)")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--out", default="runs/bench_service")
    args = parser.parse_args(argv)
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    overrides = [f"run.episodes={args.episodes}", *([f"run.max_seconds={args.seconds!r}"] if args.seconds else []),
                 *args.overrides]
    started = time.perf_counter()
    runs = {"inline": run_inline(args.config, overrides, out / "inline"),
            "service": run_service(args.config, overrides, out / "service")}
    print(f"config {args.config} {overrides}; {psutil.cpu_count()} CPUs; {time.perf_counter() - started:.0f}s total")
    print(f"{'runner':10s} {'updates/s':>10s} {'env steps/s':>12s} {'updates':>8s} {'env steps':>10s} {'window s':>9s} "
          f"{'peak PSS GiB':>13s}")
    for name, (r, memory) in runs.items():
        print(f"{name:10s} {r['updates_per_s']:10.1f} {r['env_steps_per_s']:12.1f} {r['updates']:8d} "
              f"{r['env_steps']:10d} {r['seconds']:9.1f} {memory.peak_pss / 2**30:13.2f}")
    memory = runs["service"][1]
    print(f"service memory, driver + all {memory.processes} Ray processes: peak PSS {memory.peak_pss / 2**30:.2f} GiB "
          f"(peak RSS sum {memory.peak_rss / 2**30:.2f} GiB, shared pages counted once per process)")
    inline, service = runs["inline"][0], runs["service"][0]
    print(f"ratio service / inline: {service['updates_per_s'] / inline['updates_per_s']:.2f} updates/s, "
          f"{service['env_steps_per_s'] / inline['env_steps_per_s']:.2f} env steps/s")
    short = [name for name, (r, _) in runs.items() if r["seconds"] < MIN_WINDOW_S]
    if short:
        print(f"warning: the {' and '.join(short)} window is shorter than {MIN_WINDOW_S:.0f} s, mostly warm-up: "
              f"not a steady state; raise --episodes or --seconds")


if __name__ == "__main__":
    main()
