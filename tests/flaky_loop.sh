#!/bin/bash
# Run the whole suite N times (default 10) in a clean worktree of COMMIT (default HEAD), one log per run and one
# summary line per run with its exit code, seconds and failed tests. Usage: tests/flaky_loop.sh [COMMIT] [N]
# Run it on an otherwise idle machine; it takes about N x 5.5 min on 2 cores.
set -u
repo=$(cd "$(dirname "$0")/.." && pwd)
commit=${1:-HEAD}
runs=${2:-10}
work=$(mktemp -d /tmp/flaky.XXXXXX)
git -C "$repo" worktree add --detach "$work/tree" "$commit" >/dev/null
trap 'git -C "$repo" worktree remove --force "$work/tree"' EXIT
for i in $(seq "$runs"); do
  start=$(date +%s)
  (cd "$work/tree" && PYTHONPATH="$work/tree" "$repo/.venv/bin/python" -m pytest -p no:cacheprovider -rfE \
    > "$work/run_$i.log" 2>&1)
  rc=$?
  echo "run $i rc=$rc $(( $(date +%s) - start )) s $(grep -E '^(FAILED|ERROR) ' "$work/run_$i.log" | tr '\n' ' ')" \
    | tee -a "$work/summary.txt"
done
echo "logs and summary: $work"
