#!/usr/bin/env bash
# The GPU machine's one call: the device tool's `run` from the repository root, with `carry: [".whl"]`
# (made here by benchmarks/gpu_wheels.sh) and timeout_s 600:
#
#     bash benchmarks/gpu_run.sh [benchmarks/gpu_run.py options]
#
# Installs the carried wheels into $GPU_RUN_SITE (/tmp/site), describes the machine in $OUT/env.txt, checks
# that the training path imports, then runs benchmarks/gpu_run.py with --budget-s $BUDGET_S (420) under a
# hard limit of BUDGET_S + 60 s. Results: $OUT/gpu_run.json, $OUT/gpu_run.md, $OUT/profile.txt and the log
# $OUT/gpu_run.log, written as the phases end (a timeout still returns what was measured).
# Here, without a GPU (no install; the project's venv):
#     GPU_RUN_INSTALL=0 PYTHON=.venv/bin/python OUT=/tmp/gpu_run \
#         bash benchmarks/gpu_run.sh --device cpu --tiny
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO"
PYTHON="${PYTHON:-python3}"
OUT="${OUT:?set OUT to the folder for the results}"
BUDGET_S="${BUDGET_S:-420}"
SITE="${GPU_RUN_SITE:-/tmp/site}"
if ! [[ "$BUDGET_S" =~ ^[0-9]+$ ]] || [ "$BUDGET_S" -lt 1 ]; then
    echo "gpu_run.sh: BUDGET_S=$BUDGET_S: expected a whole number of seconds" >&2
    exit 2
fi
mkdir -p "$OUT"

if [ "${GPU_RUN_INSTALL:-1}" = 1 ]; then
    shopt -s nullglob
    wheels=(.whl/*.whl)
    shopt -u nullglob
    if [ ${#wheels[@]} -eq 0 ]; then
        echo "gpu_run.sh: no wheels in $REPO/.whl: run benchmarks/gpu_wheels.sh and carry .whl" >&2
        exit 2
    fi
    "$PYTHON" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" \
        "${wheels[@]}"
    export PYTHONPATH="$SITE${PYTHONPATH:+:$PYTHONPATH}"
fi
export PYTHONPATH="$REPO${PYTHONPATH:+:$PYTHONPATH}"  # the package travels as the working tree

(
    set +e
    echo "# gpu_run.sh, $(date -u +%Y-%m-%dT%H:%M:%SZ)"
    uname -a
    echo "cores: $(nproc)"
    free -g
    df -h /tmp
    if command -v nvidia-smi >/dev/null; then nvidia-smi; else echo "nvidia-smi: not found"; fi
) >"$OUT/env.txt" 2>&1
# versions, then the training path's imports: a missing package stops the call here, in one line
if ! "$PYTHON" - >>"$OUT/env.txt" 2>&1 <<'EOF'
import importlib.metadata as md
import platform

import torch

print("python", platform.python_version(), "| CUDA", torch.version.cuda, torch.cuda.is_available())
for name in ("torch", "torchrl", "tensordict", "numpy", "kornia", "gymnasium", "omegaconf", "triton"):
    try:
        print(name, md.version(name))
    except md.PackageNotFoundError:
        print(name, "is not installed")
import navformer_rl.data.synthetic, navformer_rl.objectives, navformer_rl.training.run  # noqa: E401, F401
EOF
then
    echo "gpu_run.sh: the training path does not import here:" >&2
    tail -n 5 "$OUT/env.txt" >&2
    exit 3
fi

rc=0
PYTHONUNBUFFERED=1 timeout -k 15 $((BUDGET_S + 60)) \
    "$PYTHON" benchmarks/gpu_run.py --out "$OUT" --budget-s "$BUDGET_S" "$@" 2>&1 |
    tee "$OUT/gpu_run.log" || rc=$?
echo "gpu_run.sh: exit status $rc; results in $OUT: $(ls "$OUT" | tr '\n' ' ')"
exit "$rc"
