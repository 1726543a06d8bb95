#!/usr/bin/env bash
# `make cluster-test` (docs/how-to/slurm.md): install Slurm (apt) once, start a one-node Slurm with
# accounting under a fresh temporary directory, run workflow/cluster/check.py (the tiny study on
# Slurm against a local run), then stop every daemon it started, by PID, and delete the directory.
# KEEP=1 keeps the directory (logs, both runs' results) for a look afterwards.
set -euo pipefail
REPO=$(cd "$(dirname "$0")/../.." && pwd)
PYTHON=${PYTHON:-$REPO/.venv/bin/python}
SLURM="$REPO/workflow/cluster/slurm.sh"
started=$(date +%s)
STATE=""

finish() {
  local rc=$?
  trap - EXIT INT TERM
  if [ -n "$STATE" ]; then
    "$SLURM" stop "$STATE/slurm" || rc=1
    if [ -n "${KEEP:-}" ]; then echo "cluster-test: kept $STATE"; else rm -rf "$STATE"; fi
  fi
  echo "cluster-test: $(($(date +%s) - started)) s in all (install, start, check, stop), exit $rc"
  exit "$rc"
}
trap finish EXIT
trap 'exit 130' INT TERM

[ "$(id -u)" -eq 0 ] || { echo "cluster-test: needs root (apt-get, slurmd)" >&2; exit 2; }
command -v apt-get >/dev/null || { echo "cluster-test: needs apt-get (Debian/Ubuntu)" >&2; exit 2; }

"$SLURM" install "$REPO/.cache/cluster/apt-installed.txt"
STATE=$(mktemp -d "${TMPDIR:-/tmp}/threedcal-cluster.XXXXXX")
chmod 711 "$STATE" # munged wants its socket's path reachable by every user (o+x), mktemp gives 700
mkdir "$STATE/slurm"
# SLURM_CONF, and PATH with the cluster's srun first; a failed start stops here (set -e), which an
# `eval "$(...)"` would not.
cluster_env=$("$SLURM" start "$STATE/slurm")
eval "$cluster_env"
echo "cluster-test: Slurm up after $(($(date +%s) - started)) s"
"$PYTHON" "$REPO/workflow/cluster/check.py" "$STATE/work"
