"""Fingerprint of short inline learning curves, to show that a refactoring changed no behaviour.

For each configuration below, train the inline loop (`cmcl.loop.InlineLoop`) with a fixed seed for a short budget
past the warm-up, then hash (sha256) its metrics rows (wall-clock fields dropped) and its final MADDPG weights.
Two code versions that print the same hashes produced bit-identical learning curves and weights.

Run:  python bench/curve_fingerprint.py [--episodes 160] [--out fingerprints.json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cmcl.config import load_config  # noqa: E402
from cmcl.io.rundir import RunDirectory  # noqa: E402
from cmcl.loop import InlineLoop  # noqa: E402

WALL_CLOCK = ("elapsed_s", "env_steps_per_s", "updates_per_s")
CASES = {  # name -> (config file, extra overrides)
    "spread_maddpg": ("configs/spread_maddpg.toml", []),
    "spread_per": ("configs/spread_per.toml", []),
    "spread_acl": ("configs/spread_acl.toml", []),
    "spread_acl_td_self": ("configs/spread_acl.toml", ["teams.agent.acl_variant=\"td_self\""]),
    "spread_cmcl": ("configs/spread_cmcl.toml", []),
    "spread_cmcl_per_agent_fit": ("configs/spread_cmcl.toml", ["teachers.fit_batch=\"per_agent\""]),
    "tag_cmcl": ("configs/tag_cmcl.toml", []),
}


def _strip(value):
    """A metrics row without wall-clock fields, every number as a float (True, 1 and 1.0 hash alike)."""
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in value.items() if k not in WALL_CLOCK}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    if isinstance(value, bool | int | float):
        return float(value)
    return value


def fingerprint(config_path: str, overrides: list[str], episodes: int) -> dict[str, str]:
    """sha256 of the metrics rows and of the final MADDPG state of one short inline run."""
    with tempfile.TemporaryDirectory() as tmp:
        sets = [f"run.episodes={episodes}", f"run.dir=\"{tmp}/run\"", "run.log_every=16", "run.checkpoint_every=0",
                "env.num_envs=8", "maddpg.warmup=800", "maddpg.batch_size=64", "replay.capacity=2000",
                "teachers.batch_size=32", "icm.batch_size=32", "run.seed=3", *overrides]
        config = load_config(config_path, sets)
        run_dir = RunDirectory.create(config.run.dir, config)
        loop = InlineLoop(config, run_dir, progress=None)
        loop.run()
        rows = [_strip(json.loads(line)) for line in run_dir.metrics_path.read_text().splitlines()]
        curve = hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()[:16]
        state = loop.maddpg.state_dict()
        weights = hashlib.sha256()
        for part in ("actor", "critic"):
            for key, value in sorted(state[part].items()):
                weights.update(key.encode() + value.detach().numpy().tobytes())
        return {"curve": curve, "weights": weights.hexdigest()[:16], "updates": loop.counters["updates"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=160)
    parser.add_argument("--out", help="also write the fingerprints as JSON here")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    out = {}
    for name, (path, overrides) in CASES.items():
        out[name] = fingerprint(path, overrides, args.episodes)
        print(f"{name:28s} curve {out[name]['curve']}  weights {out[name]['weights']}  updates {out[name]['updates']}",
              flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
