"""Which code a grid's result ran, and whether a comparison's runs may be tested together.

Writing: `run_provenance` is the "provenance" of a grid summary: `cmcl.run.provenance.provenance` of this checkout and
of the run's resolved config, with the commit, dirtiness and any change during the run taken from the training process's
own summary (it recorded the code when its run opened; the grid's process may have started earlier), the load over its
training (`LoadSampler`), the commits its run directory's segments recorded (`segment_commits`: a run resumed across a
code change has two), when the summary was written (`measured_utc`, "YYYY-MM-DD HH:MM", from 2026-12-05), and
`fingerprint`: sha256s of a short, deterministic inline training of the run's own settings (`services.fingerprint`),
computed in a subprocess, so that two commits can be shown to train a setting identically.

Reading: `code_version` names the code a summary ran ("<commit[:7]>", "+dirty" when the tree was dirty, "+changed" when
the checkout changed while it trained, or for summaries written before provenance existed, "unrecorded" plus a key
signature that tells the later measures code apart); `cell_versions` decides, for the runs of one comparison, whether
they ran one code, ran several whose fingerprints agree for every arm, or are mixed (then no test is run on them).
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cmcl.run.provenance import provenance
from cmcl.run.rundir import RunDirectory
from experiments.run_spec import ROOT, Run

# Keys only the later experiments/measures.py writes: a summary without provenance that has them ran later code.
LATER_MEASURES_KEYS = ("update_every", "batch_size")


def segment_commits(run_path: Path) -> list[str]:
    """The commits recorded by the run directory's summary.json over its segments (`RunDirectory.write_summary`
    keeps them), [] for a run that recorded none."""
    try:
        record = RunDirectory.open(run_path).summary()
    except FileNotFoundError:
        return []
    return list(record.get("provenance", {}).get("segment_commits", []))


def fingerprint(run: Run) -> dict[str, Any] | None:
    """The training fingerprint of `run`'s settings ({"curve", "weights", "updates"}), from
    `python -m services.fingerprint` in a subprocess; None when it fails (the reason is not the run's)."""
    config = [] if run.task == "own_env" else ["--config", str(ROOT / "configs" / (run.config or
                                                                                   f"{run.task}_{run.algorithm}.toml"))]
    sets = [s for s in run.sets if not s.startswith(("run.", "env.num_envs"))]
    if run.prey_algorithm is not None:
        sets.append(f"teams.prey.algorithm={run.prey_algorithm}")
    cmd = [sys.executable, "-m", "services.fingerprint", *config, *[a for s in sets for a in ("--set", s)]]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        return None
    return json.loads(done.stdout.strip().splitlines()[-1])


def run_provenance(run: Run, run_path: Path, load: dict[str, Any] | None) -> dict[str, Any]:
    """A grid summary's "provenance" (module docstring)."""
    run_dir = RunDirectory.open(run_path / f"n{run.stages[-1]}" if run.stages else run_path)
    out = provenance(run_dir.config_path.read_text())
    written = run_dir.summary().get("provenance") or {}  # the training process's own record of the code it ran
    if written.get("commit"):
        out.pop("changed_during_run", None)
        out.update({k: written[k] for k in ("commit", "dirty", "changed_during_run") if k in written})
    out.update(load or {}, segment_commits=segment_commits(run_dir.path),
               measured_utc=datetime.now(UTC).strftime("%Y-%m-%d %H:%M"))
    if not run.stages and run.task != "own_env":
        out["fingerprint"] = fingerprint(run)
    return out


def code_version(summary: dict[str, Any]) -> str:
    """The code a summary ran, as a short label: "29ec5ae", "29ec5ae+dirty", "29ec5ae+changed" (the checkout changed
    during the run), "29ec5ae/7a64af0" (resumed across commits), or "unrecorded" / "unrecorded, later measures" for
    summaries written before provenance existed."""
    prov = summary.get("provenance")
    if not prov or not prov.get("commit"):
        later = all(k in summary for k in LATER_MEASURES_KEYS)
        return "unrecorded, later measures" if later else "unrecorded"
    commits = [prov["commit"], *[c for c in prov.get("segment_commits", []) if c != prov["commit"]]]
    label = "/".join(c[:7] for c in commits)
    return label + ("+dirty" if prov.get("dirty") else "") + ("+changed" if prov.get("changed_during_run") else "")


def _fingerprint_key(summary: dict[str, Any]) -> str | None:
    fp = (summary.get("provenance") or {}).get("fingerprint")
    return None if not fp else f"{fp.get('curve')}:{fp.get('weights')}"


def cell_versions(runs: Iterable[dict[str, Any]]) -> tuple[str, bool]:
    """(label, testable) for the runs of one comparison.

    One code version: (that version, True). Several: testable only if every run carries a training fingerprint and
    within each arm all fingerprints agree (the versions train that arm identically); the label then lists the
    versions and says so. Otherwise ("mixed: v1 (n runs), v2 (m runs)", False). A dirty or unrecorded version never
    vouches for itself across versions."""
    runs = list(runs)
    versions: dict[str, int] = {}
    for r in runs:
        versions[code_version(r)] = versions.get(code_version(r), 0) + 1
    if len(versions) == 1:
        return next(iter(versions)), True
    by_arm: dict[str, set[str | None]] = {}
    for r in runs:
        by_arm.setdefault(str(r.get("arm") or r.get("algorithm")), set()).add(_fingerprint_key(r))
    listed = ", ".join(f"{v} ({n} runs)" for v, n in sorted(versions.items()))
    if all(None not in keys and len(keys) == 1 for keys in by_arm.values()):
        return f"{listed}; fingerprints agree", True
    return f"mixed: {listed}", False
