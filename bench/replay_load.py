"""Load test of the replay server: sustained inserts, samples, learner feedback and teacher / ICM score updates.

One `ReplayServer` in this process (no Ray: the server's own cost), fed with real rollout chunks (spread_cmcl,
random-policy `RolloutWorker`) at the pace the service keeps (one learner call of `service.updates_per_call`
minibatches per 16 × updates_per_call inserted env steps; teacher and ICM work at their ratios). The peer is the
same server with its durable store (`cmcl.io.durable`: log of every chunk and event, snapshots) against one
without, in the same process, alternating phases. Prints per-operation throughput and p50 / p99 latency, the RSS
sampled every `--rss-every` seconds, its slope once the buffer is full (target: flat), and the ratio of the
durable server's insert throughput to the in-memory one.

    python bench/replay_load.py [--seconds 120] [--snapshot-every 30]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cmcl.config import load_config  # noqa: E402
from cmcl.replay.messages import CURIOSITY, DIFFICULTY, LearnerFeedback, Scorer, Scores  # noqa: E402
from services.roles.replay_server import ReplayServer  # noqa: E402
from services.roles.rollout import RolloutWorker  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


class LatencyHistogram:
    """Fixed-memory latency record: counts in log-spaced bins from 1 µs to 100 s (0.5% wide), so that recording
    millions of calls does not grow the process (the RSS slope must be the server's, not the bench's)."""

    EDGES = np.geomspace(1e-6, 100.0, 3700)

    def __init__(self) -> None:
        self.counts = np.zeros(self.EDGES.size + 1, np.int64)
        self.calls, self.max = 0, 0.0

    def add(self, seconds: float) -> None:
        self.counts[np.searchsorted(self.EDGES, seconds)] += 1
        self.calls, self.max = self.calls + 1, max(self.max, seconds)

    def percentile(self, q: float) -> float:
        """The q-th percentile in seconds (the upper edge of the bin it falls in, at most the largest call)."""
        k = np.searchsorted(np.cumsum(self.counts), q / 100.0 * self.calls)
        return min(float(self.EDGES[min(k, self.EDGES.size - 1)]), self.max)


def timed(latencies: dict[str, LatencyHistogram], name: str, fn, *args):
    """fn(*args), its wall time recorded in latencies[name] (seconds)."""
    start = time.perf_counter()
    out = fn(*args)
    latencies[name].add(time.perf_counter() - start)
    return out


def drive(server: ReplayServer, chunks: list, seconds: float, snapshot_every: float, rss_every: float,
          rng: np.random.Generator) -> dict:
    """Run the mixed load for `seconds`; returns latencies per operation, RSS samples and counts."""
    cfg, layout = server.config, server.layout
    latencies: dict[str, LatencyHistogram] = defaultdict(LatencyHistogram)
    rss, process = [], psutil.Process()
    start = last_rss = last_snap = time.perf_counter()
    seq = 0
    while (now := time.perf_counter()) - start < seconds:
        chunk = chunks[seq % len(chunks)]
        status = timed(latencies, "insert", server.insert, dataclasses.replace(chunk, seq=seq))
        seq += 1
        while status.allowed_updates >= cfg.service.updates_per_call:
            batch, status = timed(latencies, "sample", server.sample, cfg.service.updates_per_call)
            td = rng.random(batch.slots.shape).astype(np.float32)
            status = timed(latencies, "feedback", server.learner_result,
                           LearnerFeedback(batch.slots, batch.generations, td))
        for fold, allowed in enumerate(status.teacher_allowed):
            if allowed >= cfg.service.fit_steps_per_call:
                work, _ = timed(latencies, "teacher_work", server.work, Scorer(DIFFICULTY, (fold,)),
                                cfg.service.fit_steps_per_call)
                if work is not None:
                    errors = rng.random((work.score.slots.size, len(layout.teacher_agents), 1)).astype(np.float32)
                    timed(latencies, "teacher_scores", server.write,
                          Scores(work.scorer, work.score.slots, work.score.generations, errors, work.updates))
        if status.icm_allowed >= cfg.service.fit_steps_per_call:
            work, _ = timed(latencies, "icm_work", server.work, Scorer(CURIOSITY), cfg.service.fit_steps_per_call)
            if work is not None:
                rho = rng.random((work.score.slots.size, len(layout.icm_agents))).astype(np.float32)
                timed(latencies, "curiosity_scores", server.write,
                      Scores(work.scorer, work.score.slots, work.score.generations, rho, work.updates))
        if server.store is not None and now - last_snap >= snapshot_every:
            timed(latencies, "snapshot", server.snapshot)
            last_snap = now
        if now - last_rss >= rss_every:
            rss.append((now - start, process.memory_info().rss / 2**20, server.replay.size))
            last_rss = now
    return {"latencies": latencies, "rss": rss, "seconds": time.perf_counter() - start, "inserts": seq,
            "env_steps": server.counters["inserts"], "updates": server.counters["updates"]}


def rss_slope(rss: list[tuple[float, float, int]], capacity: int) -> float | None:
    """MiB per minute of RSS over the samples taken once the buffer was full (least squares), None if < 3."""
    full = [(t, m) for t, m, size in rss if size >= capacity]
    if len(full) < 3:
        return None
    t, m = np.array(full).T
    return float(np.polyfit(t / 60.0, m, 1)[0])


def report(name: str, run: dict, capacity: int) -> None:
    """Print one server's throughput, latency percentiles and RSS slope."""
    rate = {k: run[k] / run["seconds"] for k in ("inserts", "env_steps", "updates")}
    print(f"\n{name}: {rate['inserts']:.1f} inserts/s ({rate['env_steps']:.0f} env steps/s), "
          f"{rate['updates']:.0f} updates/s over {run['seconds']:.0f} s")
    print(f"  {'operation':18s} {'calls':>7s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s}")
    for op, hist in sorted(run["latencies"].items()):
        print(f"  {op:18s} {hist.calls:7d} {1e3 * hist.percentile(50):8.2f} {1e3 * hist.percentile(99):8.2f} "
              f"{1e3 * hist.max:8.2f}")
    slope = rss_slope(run["rss"], capacity)
    last = run["rss"][-1][1] if run["rss"] else float("nan")
    print(f"  RSS {last:.0f} MiB at the end; slope once full: "
          + ("not enough samples" if slope is None else f"{slope:+.2f} MiB/min"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="per server")
    parser.add_argument("--snapshot-every", type=float, default=30.0)
    parser.add_argument("--rss-every", type=float, default=3.0)
    args = parser.parse_args(argv)
    config = load_config(ROOT / "configs" / "spread_cmcl.toml")
    worker = RolloutWorker(config.to_dict(), 0, 0)
    chunks = [worker.rollout(None)[0] for _ in range(16)]
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, store in (("in-memory", None), ("durable", str(Path(tmp) / "replay"))):
            server = ReplayServer(config.to_dict(), store_dir=store, seed=0)
            runs[name] = drive(server, chunks, args.seconds, args.snapshot_every, args.rss_every,
                               np.random.default_rng(0))
            report(name, runs[name], config.replay.capacity)
            if store is not None:
                size = sum(p.stat().st_size for p in Path(store).iterdir())
                print(f"  store on disk at the end: {size / 2**20:.1f} MiB")
    ratio = (runs["durable"]["inserts"] / runs["durable"]["seconds"]) / (
        runs["in-memory"]["inserts"] / runs["in-memory"]["seconds"])
    print(f"\nratio durable / in-memory insert throughput: {ratio:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
