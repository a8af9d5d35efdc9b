"""The stall analysis of a curriculum grid: how long each run sat at about three landmarks of four, what
its agents did there, and what the curriculum was doing, from the run directories the grid trained in.

    python -m lab stalls GRID_FOLDER        (e.g. lab/results/curriculum; reads GRID_FOLDER/runs/*)

Writes one small JSON per finished run to GRID_FOLDER/stalls/<run id>.json (committed with the summaries; the run
directories are not), and the report turns them into the per-arm table of lab/RESULTS.md (`stall_table`).

Per run:
* `plateau_episodes`: episodes whose 100-episode moving average of coverage lies in [0.65, 0.85]
  (`cmcl.run.stalls.on_plateau`), and `plateau_middle`, the episode in the middle of that time;
* `early`: means over the progress rows while λ < 0.5 (the only time KP excludes any row, ALGORITHM.md A1) of the
  sampling ESS and the share of reward-bearing rows sampled and in the buffer (averaged over agents), and of what
  the learner was trained on then (`early_learner`, rows from episode WARM_UP on): the critic's loss on its sampled
  minibatches, their Q (minus the actor's loss, eq. 4: the mean Q of the actor's own actions on those rows), and
  for the curriculum arms the mean normalised difficulty ĉ of the sampled rows against the buffer's;
* `at_plateau` (runs with a plateau of at least MIN_PLATEAU episodes): the held-out anatomy of the misses
  (`cmcl.run.stalls.miss_anatomy`, 200 worlds) of the checkpoint nearest `plateau_middle` (`policy_checkpoints`: a run
  of the service's format keeps only the learner's last two checkpoints, so for it that is one of the end's), the
  agent most often on no
  landmark, and the curriculum's state at the progress row nearest that episode (λ, ESS, that agent's and the
  other agents' reward-bearing rows, sampled / buffer).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from cmcl.io.atomic import atomic_write_bytes
from cmcl.run.evaluate import evaluate_policy, load_policy
from cmcl.run.provenance import provenance
from cmcl.run.rundir import RunDirectory
from cmcl.run.stalls import MissAnatomy, on_plateau
from experiments.store import ResultsStore
from lab.report.stats import fmt

MIN_PLATEAU = 1000  # episodes on the plateau before its anatomy is taken
EARLY_LAMBDA = 0.5  # KP excludes rows only while λ < 0.5 (2λ < 1 under rank difficulty)
ANATOMY_WORLDS = 200
PLATEAU = (0.65, 0.85)


WARM_UP = 600  # episodes before the learner measures of `early` count (the first updates start from random nets)
LEARNER_KEYS = ("critic_loss", "q_sampled", "difficulty_sampled", "difficulty_buffer")  # added to `early`


def _mean_over_agents(rows: list[dict[str, Any]], key: str) -> float:
    return float(np.mean([np.mean(r["sampling"][key]) for r in rows])) if rows else float("nan")


def early_learner(progress: list[dict[str, Any]]) -> dict[str, float | None]:
    """What the learner was trained on while λ < EARLY_LAMBDA, from episode WARM_UP on: means over those progress
    rows and over agents of critic_loss (its sampled minibatches' weighted MSE, eq. 5), q_sampled (minus the
    actor's loss: mean Q of the actor's own actions on its sampled rows, eq. 4; continuous actions) and, where the
    rows carry the curriculum's diagnostics (ACL, CMCL), difficulty_sampled / difficulty_buffer (mean ĉ, after the
    arm's difficulty transform, of the sampled rows and of the buffer). None where no row has the measure."""
    rows = [r for r in progress if r["lambda"] < EARLY_LAMBDA and r["episodes"] >= WARM_UP]

    def mean(values: list[float]) -> float | None:
        return float(np.mean(values)) if values else None

    curriculum = [r["curriculum"] for r in rows if r.get("curriculum")]
    return {"critic_loss": mean([float(np.mean(r["critic_loss"])) for r in rows if "critic_loss" in r]),
            "q_sampled": mean([-float(np.mean(r["actor_loss"])) for r in rows if "actor_loss" in r]),
            "difficulty_sampled": mean([float(np.mean(c["difficulty_sampled"])) for c in curriculum]),
            "difficulty_buffer": mean([float(np.mean(c["difficulty_buffer"])) for c in curriculum])}


def analyse_run(run_path: Path, arm: str) -> dict[str, Any] | None:
    """The stall record of one run directory of arm `arm` (module docstring); None when the run has not finished
    its budget."""
    run = RunDirectory.open(run_path)
    config = run.config()
    episodes = list(run.rows("episode"))
    if len(episodes) < config.run.episodes:
        return None
    coverage = np.array([r["coverage"] for r in episodes], dtype=np.float64)
    plateau = np.flatnonzero(on_plateau(coverage, *PLATEAU))
    progress = [r for r in run.rows("progress") if "sampling" in r]
    early = [r for r in progress if r["lambda"] < EARLY_LAMBDA]
    record: dict[str, Any] = {
        "id": run_path.name, "arm": arm,
        "seed": int(config.run.seed), "plateau_episodes": int(plateau.size),
        "plateau_middle": int(np.median(plateau)) + 1 if plateau.size else None,
        "early": {"rows": len(early), "ess": _mean_over_agents(early, "ess_fraction"),
                  "reward_rows_sampled": _mean_over_agents(early, "reward_rows_sampled"),
                  "reward_rows_buffer": _mean_over_agents(early, "reward_rows_buffer"), **early_learner(progress)},
        "at_plateau": None,
    }
    if record["plateau_episodes"] >= MIN_PLATEAU:
        record["at_plateau"] = _at_plateau(run, config, record["plateau_middle"], progress)
    return record


def policy_checkpoints(run: RunDirectory) -> dict[int, Any]:
    """The run's policy checkpoints that pass their checks, by the episode each was written at: the learner's
    verified generations (the service's format, which both runners write: the newest and the one before it,
    services/roles/learner.py; each placed at the last episode row acted with its weight version or an older one), and
    those of the inline runner's own format of before 8dbaee8 (ckpt_<episodes>.pt, read as files)."""
    import io

    import torch

    from cmcl.io.verified import VerifiedFile
    from cmcl.run.rundir import PolicyCheckpoint

    found: dict[int, Any] = {int(p.stem.split("_")[1]): p for p in sorted(run.checkpoints.glob("ckpt_*.pt"))}
    learner, below = VerifiedFile(run.service_dir / "learner.pt"), None
    rows = [(int(r.get("weight_version", 0)), int(r["episodes"])) for r in run.rows("episode")]
    while True:
        loaded = learner._newest(below=below)
        if loaded.payload is None or loaded.generation is None:
            return found
        path = learner.file_of(loaded.generation)
        state = torch.load(io.BytesIO(loaded.payload), map_location="cpu", weights_only=True)
        version = int(state.get("version", 0))  # the weights' version; an episode row names the one it acted with
        episode = max((e for v, e in rows if v <= version), default=0)
        found.setdefault(episode, PolicyCheckpoint(path, state, path.stat().st_mtime))
        below = loaded.generation


def _checkpoint_episode(checkpoint: Any, checkpoints: dict[int, Any]) -> int:
    return next(e for e, c in checkpoints.items() if c is checkpoint)


def _at_plateau(run: RunDirectory, config: Any, middle: int, progress: list[dict[str, Any]]) -> dict[str, Any]:
    """The anatomy of the checkpoint nearest episode `middle` (`policy_checkpoints`), and the curriculum's state
    then."""
    checkpoints = policy_checkpoints(run)
    if not checkpoints:
        return {"error": "no checkpoints"}
    nearest = checkpoints[min(checkpoints, key=lambda episodes: abs(episodes - middle))]
    held_out = evaluate_policy(config, load_policy(config, nearest), ANATOMY_WORLDS, seed=int(config.run.seed))
    anatomy = MissAnatomy(**held_out["misses"])
    idle = int(np.argmax(anatomy.agent_idle_share))
    state: dict[str, Any] = {}
    if progress:
        row = min(progress, key=lambda r: abs(r["episodes"] - middle))
        sampled, buffer = row["sampling"]["reward_rows_sampled"], row["sampling"]["reward_rows_buffer"]
        others = [a for a in range(len(sampled)) if a != idle]
        state = {"episode": row["episodes"], "lambda": row["lambda"],
                 "ess": float(np.mean(row["sampling"]["ess_fraction"])),
                 "idle_agent_reward_rows": [sampled[idle], buffer[idle]],
                 "other_agents_reward_rows": [float(np.mean([sampled[a] for a in others])),
                                              float(np.mean([buffer[a] for a in others]))]}
    return {"checkpoint_episode": _checkpoint_episode(nearest, checkpoints), "coverage": held_out["coverage"],
            "anatomy": held_out["misses"], "idle_agent": idle,
            "idle_agent_share": anatomy.agent_idle_share[idle],
            "idle_agent_wall_share": anatomy.agent_wall_share[idle], "curriculum": state}


def analyse_folder(folder: str | Path, report=print) -> list[Path]:
    """Write GRID_FOLDER/stalls/<run id>.json for every run of GRID_FOLDER/runs that has a summary (a finished run;
    its arm is the summary's) and no stall record yet; a record written before the learner measures existed gets
    them added to its `early` part (from the run's progress rows; nothing else of it is recomputed)."""
    folder = Path(folder)
    out_dir = folder / "stalls"
    arms = {r["id"]: r.get("arm") for r in ResultsStore(folder).load()}
    written = []
    for run_path in sorted(p for p in (folder / "runs").glob("*") if p.is_dir()):
        target = out_dir / f"{run_path.name}.json"
        if target.exists():
            old = json.loads(target.read_text())
            if not set(LEARNER_KEYS) <= set(old["early"]):
                progress = [r for r in RunDirectory.open(run_path).rows("progress") if "sampling" in r]
                old["early"].update(early_learner(progress))
                atomic_write_bytes(target, json.dumps(old, indent=1).encode())
                written.append(target)
            continue
        if arms.get(run_path.name) is None:
            continue
        record = analyse_run(run_path, arms[run_path.name])
        if record is None:
            continue
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(target, json.dumps({**record, "provenance": provenance()}, indent=1).encode())
        written.append(target)
        report(f"{run_path.name}: plateau {record['plateau_episodes']} episodes")
    return written


def load_stalls(folder: str | Path) -> list[dict[str, Any]]:
    """Every stall record of a grid folder, sorted by run id."""
    return [json.loads(p.read_text()) for p in sorted((Path(folder) / "stalls").glob("*.json"))]


def stall_table(records: list[dict[str, Any]], arm_labels: dict[str, str]) -> str:
    """Markdown, one row per arm: runs, plateau episodes (mean, min–max), runs with a plateau of ≥ MIN_PLATEAU, the
    early sampling (λ < 0.5), and at the plateaus: the idle agent's share of worlds on no landmark and at a wall,
    the miss classes, and the idle agent's reward-bearing rows against the other agents'."""
    if not records:
        return "no runs analysed yet"
    lines = ["| arm | runs | episodes on the plateau: mean (min–max) | runs with ≥ 1,000 | λ < 0.5: ESS, reward rows "
             "sampled / buffer | at the plateau: idle agent on no landmark / at a wall | misses: crowded / short / "
             "far | reward rows of the idle agent vs the others (sampled / buffer) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for arm, label in arm_labels.items():
        rs = [r for r in records if r["arm"] == arm]
        if not rs:
            continue
        plateau = [r["plateau_episodes"] for r in rs]
        early = [r["early"] for r in rs if r["early"]["rows"]]
        stalled = [r["at_plateau"] for r in rs if r["at_plateau"] and "anatomy" in r["at_plateau"]]
        mean = lambda xs: float(np.mean(xs)) if xs else float("nan")  # noqa: E731
        cells = [label, str(len(rs)), f"{mean(plateau):,.0f} ({min(plateau):,}–{max(plateau):,})",
                 f"{len(stalled)}/{len(rs)}",
                 f"{mean([e['ess'] for e in early]):.2f}, {mean([e['reward_rows_sampled'] for e in early]):.3f} / "
                 f"{mean([e['reward_rows_buffer'] for e in early]):.3f}" if early else "—"]
        if stalled:
            classes = [mean([s["anatomy"]["missed_by_class"][c] for s in stalled]) for c in ("crowded", "short", "far")]
            with_state = [s["curriculum"] for s in stalled if s["curriculum"]]
            cells += [f"{mean([s['idle_agent_share'] for s in stalled]):.2f} / "
                      f"{mean([s['idle_agent_wall_share'] for s in stalled]):.2f}",
                      " / ".join(f"{c:.2f}" for c in classes),
                      (f"{mean([c['idle_agent_reward_rows'][0] for c in with_state]):.3f} / "
                       f"{mean([c['idle_agent_reward_rows'][1] for c in with_state]):.3f} vs "
                       f"{mean([c['other_agents_reward_rows'][0] for c in with_state]):.3f} / "
                       f"{mean([c['other_agents_reward_rows'][1] for c in with_state]):.3f}") if with_state else "—"]
        else:
            cells += ["—", "—", "—"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def early_learner_table(records: list[dict[str, Any]], arm_labels: dict[str, str]) -> str:
    """Markdown, one row per arm: what the learner was trained on while λ < 0.5 (the `early` learner measures), each
    a mean ± 95% t half-width over the arm's runs: the critic's loss on its sampled rows, their Q, the sampled
    rows' mean difficulty against the buffer's (curriculum arms), and the reward-bearing rows sampled / buffer."""
    with_learner = [r for r in records if r["early"].get("critic_loss") is not None]
    if not with_learner:
        return "no runs analysed yet"
    lines = ["| arm | runs | critic loss on the sampled rows | Q of the actor's actions on them | difficulty ĉ: "
             "sampled / buffer | reward rows: sampled / buffer |", "| --- | --- | --- | --- | --- | --- |"]
    for arm, label in arm_labels.items():
        early = [r["early"] for r in with_learner if r["arm"] == arm]
        if not early:
            continue
        difficulty = [e for e in early if e.get("difficulty_sampled") is not None]
        cells = [label, str(len(early)), fmt([e["critic_loss"] for e in early], 3),
                 fmt([e["q_sampled"] for e in early], 1),
                 (f"{np.mean([e['difficulty_sampled'] for e in difficulty]):.2f} / "
                  f"{np.mean([e['difficulty_buffer'] for e in difficulty]):.2f}") if difficulty else "—",
                 f"{np.mean([e['reward_rows_sampled'] for e in early]):.3f} / "
                 f"{np.mean([e['reward_rows_buffer'] for e in early]):.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
