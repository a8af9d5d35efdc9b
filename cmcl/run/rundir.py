"""A run directory: resolved config, metrics as JSON lines, atomic checkpoints.

Where it sits: both runners (`python -m cmcl train | resume`) write here; `cmcl.run.evaluate` and the plots read here.
Layout of `<dir>/`:
  config.toml            the resolved configuration (read back with `config()`; one written by an older version
                         with a key this one does not know is refused, cmcl.config.load_stored_config)
  metrics.jsonl          one JSON object per line (episode rows and update rows, each with a "kind";
                         cmcl.io.metrics_log)
  run.lock               the one writer's lock (cmcl.run.runlock)
  summary.json           the runner's last summary (how the run ended, its counters, its provenance)
  checkpoints/service/   both runners: each role's checkpoint generations and manifest (cmcl.io.verified), the
                         replay store, the supervisor's counters (`service_paths`)
`newest_policy()` finds the newest verified policy: evaluation, the end-of-run report and resume ask it, never a file
name. The inline runner's own format of older versions (checkpoints/ckpt_<episodes:08d>.pt) is refused.
"""

from __future__ import annotations

import io
import json
import re
import shutil
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cmcl.config import Config, dump_toml, load_stored_config
from cmcl.io.atomic import atomic_write_bytes
from cmcl.io.metrics_log import MetricsLog, json_safe
from cmcl.io.resume_hint import resume_command
from cmcl.io.verified import CheckpointError, VerifiedFile
from cmcl.replay.snapshot import OlderRunError, older_run
from cmcl.run.provenance import code_at_start, provenance

CHECKPOINT_GLOB = "ckpt_*.pt"  # the inline runner's own checkpoints of older versions: refused
# what a start that failed before its first episode leaves at the top of its run directory (with a `checkpoints/`
# tree holding no data): nothing a retry must keep (`RunDirectory.never_trained`)
START_LEFTOVERS = ("config.toml", "run.lock", "ray_shutdown.log")
SERVICE_ROLES = ("learner", "icm")  # roles whose checkpoint is one VerifiedFile at checkpoints/service/<role>.pt


class ForeignFolderError(FileExistsError):
    """A new run's run.dir holds files, and no run (no config.toml): none of them is touched."""


@dataclass(frozen=True)
class PolicyCheckpoint:
    """A run's policy checkpoint that passed its checks: the file, its decoded state (torch tensors;
    `state["maddpg"]` holds the policy) and the file's modification time (seconds since the epoch)."""

    path: Path
    state: dict[str, Any]
    mtime: float


class RunDirectory:
    """Owns one run's output folder. `create` for a new run, `open` to resume or evaluate one."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.checkpoints = self.path / "checkpoints"
        self.metrics_path = self.path / "metrics.jsonl"
        self.config_path = self.path / "config.toml"
        self.metrics = MetricsLog(self.metrics_path)
        self.refused_policies: list[str] = []  # what the last `newest_policy` refused on its way ("file: reason")

    @classmethod
    def create(cls, path: str | Path, config: Config, *, overwrite: bool = False) -> RunDirectory:
        """Make the folder and write the resolved config. Refuses a folder that already holds a run (FileExistsError;
        `overwrite` starts it over), and, even with `overwrite`, a folder holding anything but what a run's start
        leaves that is no run (ForeignFolderError: no config.toml; before, --overwrite deleted its checkpoints/ and
        metrics.jsonl). Starting over removes the old run's checkpoints, metrics.jsonl and summary.json."""
        code_at_start()  # the code this run trains with, before anything can change the checkout (cmcl.run.provenance)
        run = cls(path)
        if not run.config_path.exists() and run.path.is_dir() and not run.never_trained():  # --overwrite too
            foreign = sorted(e.name for e in run.path.iterdir() if e.name not in START_LEFTOVERS)
            raise ForeignFolderError(f"run.dir {str(run.path)!r} holds files that are not a run's "
                                     f"({', '.join(foreign[:4])}{', ...' if len(foreign) > 4 else ''}); nothing there "
                                     "is touched: choose a new or empty folder")
        restart = run.config_path.exists() and not overwrite and run.stopped_before_a_checkpoint()
        if restart:  # what the error line of its stop said: make room, then start the run again
            overwrite = True
        if run.config_path.exists() and not overwrite and not run.never_trained():
            raise FileExistsError(
                f"run.dir {str(run.path)!r} already holds a run: continue it with {resume_command(run.path)}, start "
                "over with --overwrite, or choose another run.dir")
        run.check_metrics_file()
        if overwrite:  # start over: no old metrics, no old checkpoint a role could restore itself from, and no old
            shutil.rmtree(run.checkpoints, ignore_errors=True)  # summary (its ending, its commits: the new run's
            run.metrics_path.unlink(missing_ok=True)  # summary would list them among its segments)
            run.summary_path.unlink(missing_ok=True)
        run.checkpoints.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(run.config_path, dump_toml(config).encode())
        return run

    def never_trained(self) -> bool:
        """Whether this folder holds only what a start that failed before its first episode leaves: at its top no
        file but START_LEFTOVERS, and under checkpoints/ no file with any data (no metrics row, no summary, no
        checkpoint, no replay). Such a folder holds nothing to resume; a new run may take it."""
        if not self.path.is_dir():
            return False
        for entry in self.path.iterdir():
            if entry == self.checkpoints and entry.is_dir() and not entry.is_symlink():
                if any(p.is_symlink() or (p.is_file() and p.stat().st_size) or not (p.is_file() or p.is_dir())
                       for p in entry.rglob("*")):
                    return False
            elif entry.name not in START_LEFTOVERS or not entry.is_file():
                return False
        return True

    def stopped_before_a_checkpoint(self) -> bool:
        """Whether this run stopped in order, by a file it could not write (summary.json: ended "write_failure"),
        before anything a resume starts from was written (no policy checkpoint, no service replay): a new run may
        start over in it without --overwrite, as that stop's line advised (cmcl.io.write_failure)."""
        summary = self.summary()
        return (summary.get("ended") == "write_failure" and summary.get("resume_from") is None
                and not self.runners() and not any(self.service_replay_dir.glob("*")))

    def discard_failed_start(self) -> None:
        """Remove what a start that failed before its first episode left (only when `never_trained`; run.lock is the
        lock holder's to remove): a retry then meets no run in the way, and `resume` no half-made run."""
        if not self.never_trained():
            return
        for name in START_LEFTOVERS:
            if name != "run.lock":
                (self.path / name).unlink(missing_ok=True)
        if self.checkpoints.is_dir():
            for p in sorted(self.checkpoints.rglob("*"), key=lambda p: len(p.parts), reverse=True):
                p.unlink() if p.is_file() else p.rmdir()
            self.checkpoints.rmdir()

    @classmethod
    def open(cls, path: str | Path) -> RunDirectory:
        """Open an existing run folder (must hold config.toml)."""
        code_at_start()  # a resume's code, as in `create`
        run = cls(path)
        if not run.config_path.is_file():
            raise FileNotFoundError(f"{str(run.path)!r} is not a run directory (no config.toml)")
        return run

    def config(self, overrides: tuple[str, ...] = ()) -> Config:
        """The run's resolved config, with optional overrides (cmcl.config.load_stored_config: a key of an older
        version is refused in one line naming it)."""
        return load_stored_config(self.config_path, overrides)

    def log(self, row: Mapping[str, Any]) -> None:
        """Append one metrics row (a flat or nested mapping) as a JSON line (`MetricsLog.append`: a torn last line
        is first moved aside)."""
        self.metrics.append(row)

    def rows(self, kind: str | None = None) -> Iterator[dict[str, Any]]:
        """Metrics rows in order, optionally only those with row["kind"] == kind (`MetricsLog.rows`: a torn last
        line is left out, a corrupt line before other rows raises MetricsError)."""
        return self.metrics.rows(kind)

    def check_metrics_file(self) -> None:
        """MetricsError naming metrics.jsonl when something other than a file (a directory, ...) has its name."""
        self.metrics.check_file()

    def truncate_rows_after(self, episodes: int) -> None:
        """On resume: drop rows logged after the checkpoint (row["episodes"] > episodes), atomically."""
        self.metrics.truncate_after(episodes)

    def service_paths(self) -> dict[str, Path]:
        """Where each service role keeps its checkpoint (created if missing): learner / icm (VerifiedFile bases),
        replay (the replay store's folder), supervisor (its counters, JSON), teacher (the folder of the teacher
        actors' files, one per fold group)."""
        base = self.service_dir
        base.mkdir(parents=True, exist_ok=True)
        return {**{role: base / f"{role}.pt" for role in SERVICE_ROLES}, "replay": self.service_replay_dir,
                "supervisor": self.supervisor_counters, "teacher": base}

    @property
    def service_replay_dir(self) -> Path:
        """The service's replay store (cmcl.io.durable.ReplayStore), in `service_dir`."""
        return self.service_dir / "replay"

    @property
    def supervisor_counters(self) -> Path:
        """The service supervisor's counters (JSON: episodes logged, env steps, updates), in `service_dir`."""
        return self.service_dir / "supervisor.json"

    @property
    def service_dir(self) -> Path:
        """The folder of the service's checkpoints (not created; see `service_paths`)."""
        return self.checkpoints / "service"

    def runners(self) -> set[str]:
        """Which checkpoint formats are here: "service" (both runners write it) and "inline" (the inline runner's
        own format of older versions, refused)."""
        found = set()
        if any(self.checkpoints.glob(CHECKPOINT_GLOB)):
            found.add("inline")
        learner = VerifiedFile(self.service_dir / "learner.pt")
        if learner.manifest.exists() or learner.generations():
            found.add("service")
        return found

    def service_checkpoints(self) -> list[VerifiedFile]:
        """Every service role checkpoint (learner, ICM, each teacher group) that has a file in `service_dir`."""
        bases = {re.sub(r"-\d{6,}$", "", p.stem) for p in self.service_dir.glob("*-*.pt")}
        found = [VerifiedFile(self.service_dir / f"{base}.pt") for base in sorted(bases)]
        return [vf for vf in found if vf.generations()]

    def check_no_unverifiable_checkpoint(self) -> None:
        """Refuse (CheckpointError, one line naming the files) a service run in which a role has generation files
        but none that verifies and at least one with no checksum at all (its manifest lost, no digest file: files
        written before digest files existed). Such a file may hold the trained state; a resume would start the
        role afresh and its next saves would in time delete it."""
        unverifiable = [file for vf in self.service_checkpoints() if (loaded := vf.load()).payload is None
                        for file in loaded.unverifiable]
        if unverifiable:
            raise CheckpointError(
                f"{self.service_dir}: {len(unverifiable)} checkpoint file(s) cannot be verified (no manifest names "
                f"them, no .sha256 beside them): {', '.join(f.name for f in unverifiable)}; refusing to start those "
                "roles afresh over them (restore the manifest, or move the files away to start afresh)")

    def newest_policy(self) -> PolicyCheckpoint | None:
        """The learner's newest generation that matches its manifest (else the previous one), or None. Every file
        refused on the way is in `refused_policies` afterwards ("file: reason"). OlderRunError (one line) for a run
        holding only checkpoints of the inline runner's own older format."""
        import torch

        self.refused_policies = []
        learner = VerifiedFile(self.service_dir / "learner.pt")
        loaded = learner.load()
        self.refused_policies += loaded.refused
        if loaded.payload is not None and loaded.generation is not None:
            path = learner.file_of(loaded.generation)
            try:
                state = torch.load(io.BytesIO(loaded.payload), map_location="cpu", weights_only=True)
                return PolicyCheckpoint(path, state, path.stat().st_mtime)
            except (RuntimeError, OSError):
                pass
        if "inline" in self.runners():
            raise OlderRunError(older_run(f"{self.checkpoints}: checkpoints of the inline runner's own format "
                                          f"({CHECKPOINT_GLOB})"))
        return None

    @property
    def summary_path(self) -> Path:
        return self.path / "summary.json"

    def write_summary(self, summary: Mapping[str, Any]) -> Path:
        """Write the runner's summary (how the run ended, its counters) to summary.json, atomically, with the
        provenance of the code, config and machine that produced it (`cmcl.run.provenance`, key "provenance")."""
        config_text = self.config_path.read_text() if self.config_path.is_file() else None
        record = {**summary, "provenance": provenance(config_text)}
        # the commits of every segment of the run (a resume after a code change adds one), oldest first
        earlier = self.summary().get("provenance", {})
        seen = [*earlier.get("segment_commits", [earlier.get("commit")]), record["provenance"]["commit"]]
        record["provenance"]["segment_commits"] = list(dict.fromkeys(c for c in seen if c))
        atomic_write_bytes(self.summary_path, json.dumps(json_safe(record), indent=2, sort_keys=True).encode())
        return self.summary_path

    def summary(self) -> dict[str, Any]:
        """The runner's last summary (`write_summary`), or {} when there is none or it does not parse."""
        try:
            loaded = json.loads(self.summary_path.read_text())
        except (OSError, ValueError):
            return {}
        return loaded if isinstance(loaded, dict) else {}

