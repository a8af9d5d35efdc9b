"""The project as a user installs it: a wheel built with `pip wheel .`, installed into a fresh virtual environment,
trains with `python -m cmcl train --runner inline --config <a preset>` from a folder outside the repository.

The fresh environment gets the wheel alone (`--no-deps`); its dependencies (torch, ray, pettingzoo, ...) are this
interpreter's, reached through one `.pth` line naming this environment's site-packages, so the test needs no network
and no second copy of torch. A path line in a `.pth` file adds that folder to sys.path without running the `.pth`
files inside it, so this checkout's editable install is not seen: `cmcl` must come from the wheel, and the test
checks that it does. The wheel is built from a copy of the tracked source files, so that setuptools' build folder
is not left in the checkout.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"cmcl", "services", "experiments"}  # what the wheel may install at the top level (never lab/)


def _run(argv: list[str], cwd: Path, timeout: float = 240) -> subprocess.CompletedProcess:
    """`argv` run in `cwd` without a PYTHONPATH (a user's shell has none; a checkout on it would shadow the wheel)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)


def test_wheel_installs_and_trains_in_a_fresh_venv(tmp_path: Path):
    source, wheels = tmp_path / "source", tmp_path / "wheels"
    tracked = _run(["git", "ls-files", "pyproject.toml", "README.md", *PACKAGES], cwd=ROOT).stdout.split()
    for name in tracked:
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, source / name)
    built = _run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation", "-q",
                  "-w", str(wheels)], cwd=tmp_path)
    assert built.returncode == 0, built.stderr[-2000:]
    (wheel,) = wheels.glob("cmcl_service-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        tops = {name.split("/")[0] for name in archive.namelist() if not name.split("/")[0].endswith(".dist-info")}
    assert tops <= PACKAGES, f"the wheel installs {sorted(tops - PACKAGES)} beside the packages"

    env = tmp_path / "venv"
    venv.create(env, with_pip=True)
    python = env / "bin" / "python"
    installed = _run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)], cwd=tmp_path)
    assert installed.returncode == 0, installed.stderr[-2000:]
    fresh_site = _run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=tmp_path)
    Path(fresh_site.stdout.strip(), "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")

    where = _run([str(python), "-c", "import cmcl, services; print(cmcl.__file__); print(services.__file__)"],
                 cwd=tmp_path)
    assert where.returncode == 0, where.stderr[-2000:]
    assert all(Path(line).is_relative_to(env) for line in where.stdout.split()), where.stdout

    run_dir = tmp_path / "run"
    trained = _run([str(python), "-m", "cmcl", "train", "--runner", "inline",
                    "--config", str(ROOT / "configs" / "spread_maddpg.toml"),
                    "--set", "run.episodes=48", "--set", "maddpg.warmup=256", "--set", "env.num_envs=4",
                    "--set", f"run.dir={run_dir}", "--no-eval"], cwd=tmp_path)
    assert trained.returncode == 0, trained.stdout[-2000:] + trained.stderr[-2000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["episodes"] == 48 and summary["updates"] > 0, summary
