#!/usr/bin/env bash
# One entry point for a fresh machine: creates .venv next to this script, installs navformer_rl (CPU torch),
# then runs
#   ./run.sh demo [navformer demo options]   - the end-to-end demo
#   ./run.sh test [pytest options]           - the test suite (run from the repository root)
# Any other first word is passed to the `navformer` CLI (e.g. ./run.sh collect --help). Relative paths in
# the arguments (--out, --checkpoint, data.*_path=, output_dir=) are read from the directory you are in.
set -euo pipefail
usage() {
    sed -n '2,7p' "$0" | sed 's/^# \{0,1\}//'
}
if [ $# -eq 0 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
    usage
    exit 0
fi
REPO="$(cd "$(dirname "$0")" && pwd)"
VENV="${NAVFORMER_VENV:-$REPO/.venv}"
PY="${PYTHON:-python3}"
if [ ! -x "$VENV/bin/python" ]; then
    "$PY" -m venv "$VENV"
fi
pip_install() {
    # pip's own warnings about this machine's unused local index folders are noise for a user
    "$VENV/bin/pip" install --quiet "$@" 2>&1 | { grep -v "is ignored: it is neither a file nor a directory" || true; }
}
stamp="$VENV/.navformer-installed-$(sha256sum < "$REPO/pyproject.toml" | cut -c1-16)"
if [ ! -f "$stamp" ]; then
    # torch first, pinned, so nothing later pulls the multi-GB CUDA build from the registry.
    # A machine with a local CPU wheel folder (/opt/wheels here) uses it; elsewhere set
    # NAVFORMER_TORCH_INDEX to PyTorch's CPU wheel index.
    torch_args=("torch==2.13.0")
    if [ -d /opt/wheels ]; then torch_args+=(--find-links /opt/wheels); fi
    if [ -n "${NAVFORMER_TORCH_INDEX:-}" ]; then torch_args+=(--extra-index-url "$NAVFORMER_TORCH_INDEX"); fi
    pip_install "${torch_args[@]}"
    pip_install -e "$REPO[dev]"
    touch "$stamp"
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
