#!/usr/bin/env bash
# One entry point for a fresh machine: creates .venv next to this script, installs navformer_rl (CPU torch;
# about 2 minutes the first time), then runs a command:
#   ./run.sh demo [options]         end to end: collect -> train -> evaluate -> report (8-15 min, 2 cores)
#   ./run.sh test [pytest options]  the test suite (run from the repository root)
# and every other `navformer` command:
#   world-demo   a seeded maze with moving robots: top-down map + egocentric video
#   collect      collect the offline datasets (D_e, D_ca, D_ssl)
#   train        train NavFormer (or an ablation / the DT baseline) on D_e / D_ca / D_ssl
#   validate     teacher-forced action loss of checkpoints on held-out D_e / D_ca
#   average-checkpoints  one checkpoint from the mean of a run's checkpoints' weights (an opt-in)
#   train-ppo    train the DSAC / MA-TDN baselines online with PPO
#   evaluate     measure SR / SPL / CR of a method on fixed episodes (and make-episodes / report / seeds / compare / diagnose / strip)
#   pretrained   list the shipped weights (pretrained:NAME), or ship a trained run
#   export       write a dataset in another tool's format (minari)
# `./run.sh COMMAND --help` shows a command's options. Relative paths in the arguments (--out,
# --checkpoint, data.*_path=, output_dir=) are read from the directory you are in.
set -euo pipefail
usage() {
    sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'
}
say() {
    echo "run.sh: $*" >&2
}
if [ $# -eq 0 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
    usage
    exit 0
fi
REPO="$(cd "$(dirname "$0")" && pwd)"
VENV="${NAVFORMER_VENV:-$REPO/.venv}"
PY="${PYTHON:-python3}"
if [ ! -x "$VENV/bin/python" ]; then
    say "creating the virtual environment $VENV"
    "$PY" -m venv "$VENV"
fi
pip_install() {
    # pip's own warnings about this machine's unused local index folders are noise for a user
    "$VENV/bin/pip" install --quiet "$@" 2>&1 | { grep -v "is ignored: it is neither a file nor a directory" || true; }
}
# the tests also cover the optional backends (Ray, Minari), so `test` installs their extras too
extras="dev"
if [ "${1:-}" = "test" ]; then extras="dev,distributed,minari"; fi
stamp="$VENV/.navformer-installed-$(cat "$REPO/pyproject.toml" "$REPO/constraints.txt" | sha256sum | cut -c1-16)-${extras//,/-}"
if [ ! -f "$stamp" ]; then
    # torch first, pinned, so nothing later pulls the multi-GB CUDA build from the registry.
    # A machine with a local CPU wheel folder (/opt/wheels here) uses it; elsewhere set
    # NAVFORMER_TORCH_INDEX to PyTorch's CPU wheel index.
    torch_args=("torch==2.13.0")
    if [ -d /opt/wheels ]; then torch_args+=(--find-links /opt/wheels); fi
    if [ -n "${NAVFORMER_TORCH_INDEX:-}" ]; then torch_args+=(--extra-index-url "$NAVFORMER_TORCH_INDEX"); fi
    say "installing torch 2.13.0, CPU build (1 of 2, about a minute)"
    pip_install "${torch_args[@]}"
    say "installing navformer_rl and its dependencies: torchrl, tensordict, pybullet, ... (2 of 2, about a minute)"
    pip_install -c "$REPO/constraints.txt" -e "$REPO[$extras]"   # the tested versions (constraints.txt)
    touch "$stamp"
    say "installed; later runs start at once"
fi
export RL_LOGGING_LEVEL="${RL_LOGGING_LEVEL:-WARNING}"
# transparent huge pages for malloc (glibc >= 2.35; older glibc ignores it): big tensors are not page-faulted
# in afresh at every iteration (measured in docs/training.md and benchmarks/); set GLIBC_TUNABLES to override
export GLIBC_TUNABLES="${GLIBC_TUNABLES:-glibc.malloc.hugetlb=1}"
cmd="$1"
shift
case "$cmd" in
    test) cd "$REPO" && exec "$VENV/bin/python" -m pytest -q "$@" ;;
    *) exec "$VENV/bin/navformer" "$cmd" "$@" ;;
esac
