"""Fingerprint of short inline learning curves, to show that a refactoring changed no behaviour.

For each configuration below, train with the inline runner (the service's roles in one process,
`services.launch.train_in_process`) with a fixed seed for a short budget past the warm-up, then hash (sha256) its
episode rows (wall-clock fields dropped; the progress rows come on a 2 s clock) and its final MADDPG weights
(services/fingerprint.py).
Two code versions that print the same hashes produced bit-identical learning curves and weights.

Run:  python bench/curve_fingerprint.py [--episodes 160] [--out fingerprints.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cmcl.run.provenance import provenance  # noqa: E402
from services.fingerprint import fingerprint  # noqa: E402

CASES = {  # name -> (config file, extra overrides)
    "spread_maddpg": ("configs/spread_maddpg.toml", []),
    "spread_per": ("configs/spread_per.toml", []),
    "spread_acl": ("configs/spread_acl.toml", []),
    "spread_acl_td_self": ("configs/spread_acl.toml", ["teams.agent.acl_variant=\"td_self\""]),
    "spread_cmcl": ("configs/spread_cmcl.toml", []),
    "spread_cmcl_per_agent_fit": ("configs/spread_cmcl.toml", ["teachers.fit_batch=\"per_agent\""]),
    "tag_cmcl": ("configs/tag_cmcl.toml", []),
    "spread_laber": ("configs/spread_maddpg.toml", ["teams.agent.algorithm=\"laber\""]),
    "spread_laber_permuted": ("configs/spread_maddpg.toml", ["teams.agent.algorithm=\"laber\"",
                                                             "teams.agent.priority.difficulty_transform=\"permuted\""]),
}


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
        Path(args.out).write_text(json.dumps({**out, "provenance": provenance()}, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
