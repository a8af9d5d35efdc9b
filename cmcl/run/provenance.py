"""Provenance of a result: which code, which settings and which machine produced it.

Every run summary (`RunDirectory.write_summary`), every grid summary (`experiments.runner`) and the bench scripts'
outputs carry `provenance(...)`:

  commit        the git commit of the checkout the code was imported from (40 hex digits), or None when it is not a
                git checkout (an installed wheel, a container image: then `CMCL_COMMIT` names it if set), as it was
                when this process first asked (`code_at_start`: a run directory asks when the run opens), so a commit
                or checkout made while the run trains does not rename the code the run ran
  dirty         True when tracked files differ from that commit (untracked files do not count, nor the results the
                grids write, RESULTS_PATHS: a grid's tracked results.csv changes after its first run); None without git
  changed_during_run  present only when the checkout is not what it was at the start ({"commit", "dirty"} now): the
                process may have imported some of its modules from the later code (a lazy import), so its numbers
                belong to neither commit alone
  config_sha256 sha256 of the resolved config (its TOML text, `cmcl.config.dump_toml`), when one is given
  versions      {"python", "torch", "numpy", "ray"} ("absent" for a package that is not installed)
  cores         os.cpu_count() of the machine
  cpu           {"model": /proc/cpuinfo's model name, "simd": the widest vector extension it lists, "avx512" | "avx2"
                | "avx" | "sse" | "unknown"}: float kernels differ by vector width, so the same commit and seed
                need not train bit-identically on two machines (a training fingerprint is a property of code and
                machine; docs/PERFORMANCE.md)
  load_avg      the 1, 5 and 15-minute load averages when the record was made (os.getloadavg)

`LoadSampler` adds the load over a whole run (mean and max of the 1-minute load average, sampled on a cadence).
Pure: git, /proc and importlib metadata only; no torch or ray import happens here.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
import platform
import subprocess
import threading
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]  # the checkout (or site-packages) this package was imported from
VERSIONED = ("torch", "numpy", "ray")


def _git(*args: str, cwd: Path = ROOT) -> str | None:
    """stdout of `git args` in `cwd`, stripped, or None when git is missing or the folder is not a checkout."""
    try:
        done = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


RESULTS_PATHS = ("lab/results",)  # what the grids and benches write into the checkout: results, not code


def code_state(root: Path = ROOT) -> tuple[str | None, bool | None]:
    """(commit, dirty) of the checkout at `root`: dirty when a tracked file outside RESULTS_PATHS differs from the
    commit. Outside a git checkout: (CMCL_COMMIT or None, None)."""
    commit = _git("rev-parse", "HEAD", cwd=root)
    if commit is None:
        return os.environ.get("CMCL_COMMIT") or None, None
    status = _git("status", "--porcelain", "--untracked-files=no", "--", ".",
                  *(f":(exclude){p}" for p in RESULTS_PATHS), cwd=root)
    return commit, bool(status) if status is not None else None


_AT_START: dict[Path, tuple[str | None, bool | None]] = {}  # root -> code_state the first time this process asked


def code_at_start(root: Path = ROOT) -> tuple[str | None, bool | None]:
    """(commit, dirty) of the checkout at `root` the first time this process asked: the code it runs. The run
    directory asks when a run opens (cmcl.run.rundir), a bench before its run; later calls return that answer."""
    root = Path(root)
    if root not in _AT_START:
        _AT_START[root] = code_state(root)
    return _AT_START[root]


def config_digest(config_text: str) -> str:
    """sha256 hex of a resolved config's TOML text."""
    return hashlib.sha256(config_text.encode()).hexdigest()


def versions() -> dict[str, str]:
    """{"python": "3.11.x", "torch": ..., "numpy": ..., "ray": ...}; "absent" for a package not installed."""
    out = {"python": platform.python_version()}
    for name in VERSIONED:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "absent"
    return out


SIMD = (("avx512", "avx512f"), ("avx2", "avx2"), ("avx", "avx"), ("sse", "sse2"))  # (name, /proc/cpuinfo flag)


def cpu(cpuinfo: Path = Path("/proc/cpuinfo")) -> dict[str, str]:
    """{"model": the CPU's model name, "simd": the widest of SIMD's extensions its flags list} ("unknown" for what
    the file does not say, or without the file)."""
    fields: dict[str, str] = {}
    try:
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    flags = set(fields.get("flags", "").split())
    simd = next((name for name, flag in SIMD if flag in flags), "unknown")
    return {"model": fields.get("model name") or platform.processor() or "unknown", "simd": simd}


def load_average() -> list[float]:
    """[1, 5, 15]-minute load averages, rounded to 0.01."""
    return [round(x, 2) for x in os.getloadavg()]


def provenance(config_text: str | None = None, root: Path = ROOT) -> dict[str, Any]:
    """The provenance record (see the module docstring); `config_text`: the resolved config's TOML, if any."""
    commit, dirty = code_at_start(root)
    out: dict[str, Any] = {"commit": commit, "dirty": dirty}
    now = code_state(root)
    if now != (commit, dirty):
        out["changed_during_run"] = {"commit": now[0], "dirty": now[1]}
    if config_text is not None:
        out["config_sha256"] = config_digest(config_text)
    out.update(versions=versions(), cores=os.cpu_count(), cpu=cpu(), load_avg=load_average())
    return out


class LoadSampler:
    """The 1-minute load average sampled every `every_s` seconds on a daemon thread while in a `with` block.

    `summary()` -> {"load_mean": float, "load_max": float, "load_samples": int}: over the samples taken (one at
    entry, one at exit, and one per period between). Used around a grid's training subprocess."""

    def __init__(self, every_s: float = 15.0):
        if not every_s > 0:
            raise ValueError(f"every_s must be > 0, got {every_s!r}")
        self.every_s = float(every_s)
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="load-sampler")

    def _loop(self) -> None:
        while not self._stop.wait(self.every_s):
            self.samples.append(os.getloadavg()[0])

    def __enter__(self) -> LoadSampler:
        self.samples.append(os.getloadavg()[0])
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.samples.append(os.getloadavg()[0])

    def summary(self) -> dict[str, Any]:
        return {"load_mean": round(sum(self.samples) / len(self.samples), 2) if self.samples else None,
                "load_max": round(max(self.samples), 2) if self.samples else None,
                "load_samples": len(self.samples)}
