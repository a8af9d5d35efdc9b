#!/usr/bin/env bash
# deploy/wheelhouse.sh: every Python package deploy/Dockerfile installs, as wheels in deploy/wheels/, built on the
# host with the host's pip configuration (its index, certificates and proxy). The image build then installs from
# there with `pip install --no-index`: no network and no certificate inside the build, and the same wheels every
# time. Run from anywhere; PYTHON picks the interpreter (a CPython 3.11 like the image's; default: the project's
# .venv, else python3).
#
# torch is pinned to 2.13.0. Where pip's index offers only the CUDA build (PyPI), get the CPU wheel with
#   PIP_EXTRA_INDEX_URL=https://download.pytorch.org/whl/cpu deploy/wheelhouse.sh
# (on the build machine pip's find-links already holds torch-2.13.0+cpu).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OUT=$ROOT/deploy/wheels
PYTHON=${PYTHON:-$( [ -x "$ROOT/.venv/bin/python" ] && echo "$ROOT/.venv/bin/python" || echo python3 )}
"$PYTHON" -c 'import sys; assert sys.version_info[:2] == (3, 11), f"need CPython 3.11 (the image), got {sys.version}"'
# The project's dependencies (pyproject.toml) and its build requirements; the project itself is built from source in
# the image (its code changes more often than its dependencies).
mapfile -t REQUIREMENTS < <("$PYTHON" -c 'import sys, tomllib
project = tomllib.load(open(sys.argv[1], "rb"))
print("torch==2.13.0", *project["project"]["dependencies"], *project["build-system"]["requires"], sep="\n")' \
    "$ROOT/pyproject.toml")
# Kept when built from the same requirements (deploy/wheels/requirements.txt); FORCE=1 rebuilds.
if [ "${FORCE:-0}" != 1 ] && [ -f "$OUT/requirements.txt" ] && \
        [ "$(cat "$OUT/requirements.txt")" = "$(printf '%s\n' "${REQUIREMENTS[@]}")" ]; then
    echo "deploy/wheels/ is up to date with pyproject.toml (FORCE=1 rebuilds it)"
    exit 0
fi
mkdir -p "$OUT" && rm -f "$OUT"/*.whl "$OUT/requirements.txt" && echo "*" > "$OUT/.gitignore"  # never committed
"$PYTHON" -m pip wheel --quiet --wheel-dir "$OUT" "${REQUIREMENTS[@]}"
"$PYTHON" - "$OUT" <<'PY'
import pathlib, sys
wheels = sorted(pathlib.Path(sys.argv[1]).glob("*.whl"))
torch = [w.name for w in wheels if w.name.startswith("torch-")]
assert torch and all("+cpu" in n or "cu" not in n for n in torch), torch
cuda = [w.name for w in wheels if w.name.startswith("nvidia")]
assert not cuda, f"CUDA wheels in the wheelhouse (torch is not the CPU build?): {cuda}"
print(f"{len(wheels)} wheels, {sum(w.stat().st_size for w in wheels) / 2**20:.0f} MiB in {sys.argv[1]}: {torch[0]}")
PY
printf '%s\n' "${REQUIREMENTS[@]}" > "$OUT/requirements.txt"
