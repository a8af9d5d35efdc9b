"""The results store of a grid's folder: one summary per finished run, `<root>/summaries/<run id>.json`, and
`<root>/results.csv` rebuilt from them (one row per run, curves left out).

A summary is the run's fields (run_spec.Run.record) and its measures (measures.summarise). Summaries written by the
earlier `bench/reproduce.py` have the same keys and are read as they are. The earlier time-to-solve program kept
one JSON line per run in `<root>/results.jsonl` with its held-out measures nested (`held_out: {coverage, ...}`);
`load` reads those lines too, as summaries (held_out_coverage, ...; grid from the id's first word), so a folder
holds runs of both kinds. A run counts as finished when its summary exists, in either form.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from cmcl.io.atomic import atomic_write_bytes

CSV_COLUMNS = ("id", "grid", "task", "algorithm", "prey_algorithm", "ablation", "seed", "budget", "episodes",
               "env_steps", "updates", "wall_s", "episodes_to_50", "episodes_to_90", "seconds_to_50", "seconds_to_90",
               "auc_coverage", "final_ma_coverage", "final_ma_success", "mean_reward", "mean_reward_predator",
               "mean_reward_prey", "final_ma_predator_win", "held_out_coverage", "held_out_success",
               "held_out_collisions", "held_out_wall_hits", "win_vs_trained_prey", "win_vs_random_prey",
               "arm", "ess_mean", "ess_first_quarter", "reward_rows_sampled_mean", "reward_rows_buffer_mean")
LEGACY_LOG = "results.jsonl"  # the earlier time-to-solve program's store


class ResultsStore:
    """The summaries of one results folder (e.g. lab/results/curriculum)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.summaries = self.root / "summaries"

    def runs_dir(self, run_id: str) -> Path:
        """Where run `run_id` trains (its run directory)."""
        return self.root / "runs" / run_id

    def path(self, run_id: str) -> Path:
        return self.summaries / f"{run_id}.json"

    def finished(self) -> set[str]:
        """The ids of every run with a summary (either form)."""
        return {p.stem for p in self.summaries.glob("*.json")} | set(self._legacy())

    def write(self, summary: dict[str, Any]) -> Path:
        """Store one run's summary (atomically: a reader never sees half of it)."""
        self.summaries.mkdir(parents=True, exist_ok=True)
        path = self.path(summary["id"])
        atomic_write_bytes(path, json.dumps(summary).encode())
        return path

    def load(self) -> list[dict[str, Any]]:
        """Every summary, sorted by file name (then the older log's lines, in their order, unless a summary of the
        same id exists)."""
        runs = [json.loads(p.read_text()) for p in sorted(self.summaries.glob("*.json"))]
        have = {r["id"] for r in runs}
        return runs + [r for run_id, r in self._legacy().items() if run_id not in have]

    def _legacy(self) -> dict[str, dict[str, Any]]:
        path = self.root / LEGACY_LOG
        if not path.exists():
            return {}
        return {r["id"]: legacy_summary(r) for r in map(json.loads, path.read_text().splitlines()) if r}

    def write_csv(self) -> Path:
        """Rebuild <root>/results.csv from every summary file (one row per finished run; curves left out)."""
        rows = [json.loads(p.read_text()) for p in sorted(self.summaries.glob("*.json"))]
        path = self.root / "results.csv"
        with path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
        return path


def legacy_summary(record: dict[str, Any]) -> dict[str, Any]:
    """A line of the earlier time-to-solve log as a summary: grid from the id's first word, task "spread" unless
    named, the nested held-out measures flattened (held_out_<name>)."""
    out = {"grid": record["id"].split("_")[0], "task": "spread", "prey_algorithm": None, **record}
    out.pop("held_out", None)
    out.update({f"held_out_{k}": v for k, v in record.get("held_out", {}).items()})
    return out
