"""A training fingerprint: sha256s of a short, deterministic training of one configuration by the inline runner
(the service's roles called in one process: services.runtime.calls.InProcessCalls).

Two code versions that print the same fingerprint for a configuration trained it bit-identically over the
prefix (the episode rows of metrics.jsonl without wall-clock fields, and the final MADDPG weights; the progress rows
are left out: they are written every few seconds of wall clock). The report of the experiments
uses it to decide whether runs of one comparison made at different commits may be tested together
(experiments.provenance.cell_versions); bench/curve_fingerprint.py prints it for a set of configurations.

    python -m services.fingerprint --config configs/spread_hard.toml [--set k=v ...] [--episodes 160]
        prints one JSON line {"curve": 16 hex, "weights": 16 hex, "updates": int}
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

WALL_CLOCK = ("elapsed_s", "segment_s", "env_steps_per_s", "updates_per_s")
# The prefix's own settings (small, fast, past the warm-up): they override the configuration's.
PREFIX_SETS = ("service.checkpoint_every_s=1e9", "env.num_envs=8", "maddpg.warmup=800",
               "maddpg.batch_size=64", "replay.capacity=2000", "teachers.batch_size=32", "icm.batch_size=32",
               "run.seed=3")
EPISODES = 160


def _strip(value):
    """A metrics row without wall-clock fields, every number as a float (True, 1 and 1.0 hash alike)."""
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in value.items() if k not in WALL_CLOCK}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    if isinstance(value, bool | int | float):
        return float(value)
    return value


def fingerprint(config_path: str | None, overrides: list[str], episodes: int = EPISODES) -> dict:
    """{"curve", "weights": sha256[:16] hex, "updates": int} of one short inline run of the config file (None: the
    defaults) with `overrides`, then the prefix's own settings."""
    import torch

    from cmcl.config import load_config
    from cmcl.run.rundir import RunDirectory
    from services.launch import train_in_process

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        sets = [*overrides, f"run.episodes={episodes}", f"run.dir=\"{tmp}/run\"", *PREFIX_SETS]
        config = load_config(config_path, sets)
        run_dir = RunDirectory.create(config.run.dir, config)
        summary, roles = train_in_process(config, run_dir)
        rows = [_strip(row) for row in run_dir.rows("episode")]
        curve = hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()[:16]
        state = roles.learner.maddpg.state_dict()
        weights = hashlib.sha256()
        for part in ("actor", "critic"):
            for key, value in sorted(state[part].items()):
                weights.update(key.encode() + value.detach().numpy().tobytes())
        return {"curve": curve, "weights": weights.hexdigest()[:16], "updates": int(summary["updates"])}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m services.fingerprint", description=__doc__.split("\n")[0])
    parser.add_argument("--config", type=Path, default=None, help="a config file (default: the defaults)")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--episodes", type=int, default=EPISODES)
    args = parser.parse_args(argv)
    print(json.dumps(fingerprint(None if args.config is None else str(args.config), args.set, args.episodes)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
