"""One MADDPG update against the core's own matmul peak: achieved GFLOP/s, and what each change tried does to it.

The peak is measured here, in this run, on this core: the best of a few float32 `torch.mm` of 1024 x 1024 x 1024 with
one thread (and bfloat16 where the CPU has it), 2·n³ FLOP each, by the thread's CPU time (on a shared machine the
wall clock would count the waits for the core). One update is `MADDPG.update` as the learner calls it,
built from a preset (`cmcl.system.build_maddpg`), on a random minibatch of the preset's shape (obs float32[N, S, N,
od], ...; S = maddpg.batch_size); its FLOP are counted once by `torch.utils.flop_counter.FlopCounterMode` (matmuls,
forward and backward: the work a perfect kernel could not avoid), and its time is the median of interleaved rounds.

Variants (each on its own copy of the same networks, rounds interleaved so that a busy machine slows all alike):
- base: as the learner runs it (one thread, fused Adam: cmcl.learners.nets.make_adam);
- threads2: two intra-op threads (what the core limit forbids the learner on a 2-core machine: the rollout and the
  replay need the other core);
- bf16: the critic and actor steps under `torch.autocast("cpu", dtype=torch.bfloat16)` (where the CPU reports
  bf16 support);
- compile: the actor and critic modules (and their targets) wrapped by `torch.compile` (inductor; compile time is
  left out: warm-up rounds run first);
- compile_step: the whole critic step and the whole actor step (forward, backward, clip, Adam) each wrapped by
  `torch.compile` (mode `--compile-mode`, default "default"; "max-autotune-no-cudagraphs" also tunes the GEMMs).
"Trains the same" is read off a copy per variant: after `--check` updates on the same minibatches from the same
seed, the largest |Δ| of any critic weight against base's copy (0 means bit-identical).

    python bench/learner_peak.py [--config configs/spread_maddpg.toml] [--rounds 7] [--updates 50] [--check 20]
                                 [--variants base threads2 bf16 compile compile_step] [--compile-mode MODE]
    python bench/learner_peak.py --profile [--updates 50] [--top 30]

`--profile` runs `--updates` updates of base under `torch.profiler` (record_shapes) instead and prints the top ops by
self CPU time per update, then the same split by input shapes, then the share of the matmul kernels (baddbmm, bmm).

It also times the update's own typical product (one baddbmm of the minibatch's size) alone: the rate a single
kernel reaches at that size, the realistic ceiling for an update made of such products.

Prints one row per variant (ms per update, GFLOP/s, share of the float32 peak, speed over base; then the same by CPU
time: CPU ms per update (this process's CPU time, every thread, so threads2's counts both: on a shared machine the
time the update itself ran, without the waits for the core), its GFLOP/s and share of the peak; max |Δ|), base's rate
by CPU time, and a last line ``base / peak: X`` (the fraction of the measured float32
matmul peak one update achieves, by wall clock).
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from cmcl.config import load_config
from cmcl.system import build_maddpg, layout_of

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("base", "threads2", "bf16", "compile", "compile_step")
MATMULS = ("aten::baddbmm", "aten::bmm", "aten::mm", "aten::addmm", "aten::matmul")


def has_bf16() -> bool:
    """Whether this CPU advertises bfloat16 arithmetic (avx512_bf16 or amx_bf16 in /proc/cpuinfo)."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


def matmul_peak(dtype: torch.dtype, n: int = 1024, reps: int = 5) -> float:
    """GFLOP/s of the best of `reps` n x n x n matmuls of `dtype` on one thread (2·n³ FLOP each), each timed by this
    thread's CPU time (a shared core's waits left out)."""
    a, b = torch.randn(n, n).to(dtype), torch.randn(n, n).to(dtype)
    torch.mm(a, b)  # warm-up
    best = float("inf")
    for _ in range(reps):
        t0 = time.thread_time()
        torch.mm(a, b)
        best = min(best, time.thread_time() - t0)
    return 2 * n**3 / best / 1e9


def small_matmul_rate(members: int, rows: int, width: int, reps: int = 2000) -> float:
    """GFLOP/s of the update's own typical product, float32 baddbmm [members, rows, width] x [members, width, width]
    on one thread, the median of `reps` calls by this thread's CPU time: what one kernel achieves at this size (call
    overhead included)."""
    x, w, b = torch.randn(members, rows, width), torch.randn(members, width, width), torch.randn(members, 1, width)
    times = []
    for _ in range(reps):
        t0 = time.thread_time()
        torch.baddbmm(b, x, w)
        times.append(time.thread_time() - t0)
    return 2 * members * rows * width * width / statistics.median(times) / 1e9


def minibatch(config, layout, seed: int) -> dict[str, np.ndarray]:
    """One random per-owner minibatch of the preset's shapes: obs / next_obs float32[N, S, N, od], act [N, S, N, ad],
    rew [N, S, N], done [N, S]."""
    rng = np.random.default_rng(seed)
    n, s = layout.num_agents, config.maddpg.batch_size
    obs = rng.normal(size=(n, s, n, layout.obs_dim)).astype(np.float32)
    return {"obs": obs, "act": rng.uniform(-1, 1, size=(n, s, n, layout.act_dim)).astype(np.float32),
            "rew": rng.normal(size=(n, s, n)).astype(np.float32),
            "next_obs": rng.normal(size=obs.shape).astype(np.float32), "done": np.zeros((n, s), np.float32)}


def update_flop(maddpg, batch) -> int:
    """FLOP of one update (FlopCounterMode: matmuls, forward and backward), on a copy so nothing moves."""
    probe = copy.deepcopy(maddpg)
    with FlopCounterMode(display=False) as counter:
        probe.update(batch)
    return int(counter.get_total_flops())


def variant(name: str, maddpg, compile_mode: str = "default") -> tuple[object, Callable[[dict], object], int]:
    """(its own copy of the networks, one update of it, its intra-op threads)."""
    m = copy.deepcopy(maddpg)
    if name == "compile_step":  # the whole steps, backward and optimiser included (graph breaks where torch needs)
        for attr in ("_critic_step", "_actor_step"):
            setattr(m, attr, torch.compile(getattr(m, attr), mode=None if compile_mode == "default" else compile_mode))
    if name == "bf16":  # the critic and actor steps under autocast, their outputs back in float32
        for attr in ("_critic_step", "_actor_step"):
            setattr(m, attr, _autocast_bf16(getattr(m, attr)))
    if name == "compile":
        for attr in ("actor", "critic", "target_actor", "target_critic"):
            setattr(m, attr, torch.compile(getattr(m, attr)))
    return m, m.update, 2 if name == "threads2" else 1


def _autocast_bf16(step: Callable) -> Callable:
    """`step` run under bfloat16 autocast, its tensors returned as float32."""
    def run(*args, **kwargs):
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = step(*args, **kwargs)
        return tuple(t.float() for t in out)
    return run


def profile_updates(maddpg, batches: list[dict], updates: int, top: int) -> None:
    """Print the top ops of `updates` updates of a copy of `maddpg` by self CPU time (µs per update, calls per
    update), then split by input shapes, then the matmul kernels' share of the profiled time."""
    from torch.profiler import ProfilerActivity, profile

    m = copy.deepcopy(maddpg)
    for batch in batches[:3]:
        m.update(batch)
    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
        for i in range(updates):
            m.update(batches[i % len(batches)])
    for by_shape in (False, True):
        events = sorted(prof.key_averages(group_by_input_shape=by_shape), key=lambda e: -e.self_cpu_time_total)
        print(f"top {top} ops{' by input shapes' if by_shape else ''} (self CPU µs per update, calls per update):")
        for e in events[:top]:
            shapes = f"  {str(e.input_shapes)[:90]}" if by_shape else ""
            print(f"  {e.key[:55]:<55} {e.self_cpu_time_total / updates:9.1f} {e.count / updates:7.1f}{shapes}")
    events = prof.key_averages()
    total = sum(e.self_cpu_time_total for e in events)
    mm = sum(e.self_cpu_time_total for e in events if e.key in MATMULS)
    ops = sum(e.count for e in events if e.key.startswith("aten::"))
    print(f"profiled: {total / updates / 1e3:.3f} ms per update (profiler overhead included), matmul kernels "
          f"{mm / updates / 1e3:.3f} ms ({mm / total:.0%}), {ops / updates:.0f} aten calls per update")


def max_weight_gap(a, b) -> float:
    """The largest |Δ| between the critic weights of two copies."""
    pa = dict(getattr(a.critic, "_orig_mod", a.critic).named_parameters())
    pb = dict(getattr(b.critic, "_orig_mod", b.critic).named_parameters())
    return max(float((pa[k] - pb[k]).detach().abs().max()) for k in pa)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--config", default=str(ROOT / "configs" / "spread_maddpg.toml"))
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--updates", type=int, default=50, help="updates per round")
    p.add_argument("--check", type=int, default=20, help="updates of the same-training check")
    p.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS))
    p.add_argument("--compile-mode", default="default", help="torch.compile mode of compile_step")
    p.add_argument("--profile", action="store_true", help="profile base's updates instead of timing the variants")
    p.add_argument("--top", type=int, default=30, help="ops printed by --profile")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    config = load_config(args.config, ["run.dir=unused"])
    layout = layout_of(config)
    maddpg = build_maddpg(config, layout, seed=0)
    if args.profile:
        profile_updates(maddpg, [minibatch(config, layout, seed) for seed in range(8)], args.updates, args.top)
        return
    names = [v for v in args.variants if v != "bf16" or has_bf16()]
    skipped = sorted(set(args.variants) - set(names))
    batches = [minibatch(config, layout, seed) for seed in range(8)]
    peak32 = matmul_peak(torch.float32)
    peak16 = matmul_peak(torch.bfloat16) if has_bf16() else None
    flop = update_flop(maddpg, batches[0])
    small = small_matmul_rate(layout.num_agents, config.maddpg.batch_size, config.maddpg.hidden)

    runs, failed = {}, {}
    for name in names:
        try:
            m, step, threads = variant(name, maddpg, args.compile_mode)
            torch.set_num_threads(threads)
            for batch in batches[:3]:  # warm-up (compilation)
                step(batch)
            runs[name] = (m, step, threads)
        except Exception as err:  # a variant this torch cannot run is reported, not fatal
            failed[name] = f"{type(err).__name__}: {str(err).splitlines()[0][:100]}"
        finally:
            torch.set_num_threads(1)
    seconds: dict[str, list[float]] = {name: [] for name in runs}
    cpu: dict[str, list[float]] = {name: [] for name in runs}  # CPU seconds of this process (all its threads)
    for _ in range(args.rounds):
        for name, (_, step, threads) in runs.items():
            torch.set_num_threads(threads)
            t0, c0 = time.perf_counter(), time.process_time()
            for i in range(args.updates):
                step(batches[i % len(batches)])
            seconds[name].append((time.perf_counter() - t0) / args.updates)
            cpu[name].append((time.process_time() - c0) / args.updates)
            torch.set_num_threads(1)

    gaps = {}
    for name in runs:  # the same training: fresh copies, the same minibatches
        ref, (m, step, threads) = copy.deepcopy(maddpg), variant(name, maddpg, args.compile_mode)
        torch.set_num_threads(threads)
        for i in range(args.check):
            ref.update(batches[i % len(batches)])
            step(batches[i % len(batches)])
        torch.set_num_threads(1)
        gaps[name] = max_weight_gap(ref, m)

    n, s = layout.num_agents, config.maddpg.batch_size
    print(f"config {args.config}: N = {n}, S = {s}, hidden {config.maddpg.hidden}, networks "
          f"{config.maddpg.networks}; one update = {flop / 1e6:.1f} MFLOP (matmuls, forward + backward)")
    print(f"matmul peak on one core (1024³): float32 {peak32:.1f} GFLOP/s"
          + (f", bfloat16 {peak16:.1f} GFLOP/s" if peak16 else ", bfloat16: not supported by this CPU"))
    print(f"the update's own size of product (baddbmm [{n}, {s}, {config.maddpg.hidden}] x [{n}, "
          f"{config.maddpg.hidden}, {config.maddpg.hidden}]): {small:.1f} GFLOP/s ({small / peak32:.1%} of the "
          f"float32 peak)")
    print(f"{'variant':<12} {'ms/update':>10} {'GFLOP/s':>9} {'of fp32 peak':>13} {'vs base':>8} {'CPU ms':>8} "
          f"{'CPU GFLOP/s':>12} {'of peak':>8} {'max |Δw|':>10}")
    base = statistics.median(seconds["base"]) if "base" in seconds else None
    for name in runs:
        t, c = statistics.median(seconds[name]), statistics.median(cpu[name])
        speed = f"{base / t:7.2f}x" if base else "      -"
        print(f"{name:<12} {1e3 * t:10.3f} {flop / t / 1e9:9.2f} {flop / t / 1e9 / peak32:12.1%} {speed:>8} "
              f"{1e3 * c:8.3f} {flop / c / 1e9:12.2f} {flop / c / 1e9 / peak32:7.1%} {gaps[name]:10.2e}")
    for name, why in failed.items():
        print(f"{name:<10} failed: {why}")
    for name in skipped:
        print(f"{name:<10} skipped: this CPU has no bfloat16 support")
    if base:
        by_cpu = flop / statistics.median(cpu["base"]) / 1e9
        print(f"base by CPU time: {by_cpu:.2f} GFLOP/s ({by_cpu / peak32:.1%} of the peak)")
        print(f"base / peak: {flop / base / 1e9 / peak32:.3f}")


if __name__ == "__main__":
    main()
