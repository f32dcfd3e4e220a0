#!/usr/bin/env bash
# Download into .whl/ the cp312 manylinux wheels the GPU machine lacks (it has Python 3.12, torch, numpy,
# pyyaml, cloudpickle, safetensors, tqdm, ...; see shared/notes/gpu-machine.md), one version each, for
# benchmarks/gpu_run.sh. Run here, from anywhere, where pip reaches the package registry:
#
#     bash benchmarks/gpu_wheels.sh
#
# .whl/ is ignored through .git/info/exclude (added here if missing) and travels with the device tool's
# `carry: [".whl"]`. Prints each wheel and the total size (the working tree and the carried paths share
# 64 MiB). Not torch: the machine's torch 2.11 is used (ours pins 2.13); the wheels install with --no-deps.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PYTHON="${PYTHON:-python3}"
DEST="$REPO/.whl"

# What `import navformer_rl.training` and a training run import there, beyond the machine's own packages
# (tests/test_gpu_run.py checks this list against the imports of a real run). hydra-core is for the recipe.
WHEELS=(
    torchrl==0.14.1
    tensordict==0.14.3
    pyvers==0.2.3
    orjson==3.13.0
    gymnasium==1.4.0
    farama-notifications==0.0.6
    omegaconf==2.3.1
    antlr4-python3-runtime==4.9.3
    hydra-core==1.3.8
    kornia==0.9.0
    kornia_rs==0.2.0
)

if ! grep -qxF "/.whl/" "$REPO/.git/info/exclude" 2>/dev/null; then
    mkdir -p "$REPO/.git/info"
    echo "/.whl/" >>"$REPO/.git/info/exclude"
fi
rm -rf "$DEST"
mkdir -p "$DEST"
platforms=()
for tag in manylinux_2_28 manylinux_2_27 manylinux_2_17 manylinux2014 manylinux1; do
    platforms+=(--platform "${tag}_x86_64")
done
quiet_pip() {  # pip's warnings about this machine's unused local index folders are noise
    "$PYTHON" -m pip "$@" 2>&1 | { grep -v "is ignored: it is neither a file nor a directory" || true; }
}
for spec in "${WHEELS[@]}"; do
    if [ "${spec%%==*}" = antlr4-python3-runtime ]; then
        # 4.9.x (what omegaconf 2.3's parser needs) exists only as source: build its pure-Python wheel
        quiet_pip wheel --quiet --no-deps --no-binary=:all: -w "$DEST" "$spec"
        continue
    fi
    quiet_pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --abi cp312 --abi abi3 --abi none "${platforms[@]}" --platform any -d "$DEST" "$spec"
done
ls -1 "$DEST"
count=$(find "$DEST" -type f -name '*.whl' | wc -l)
if [ "$count" -ne "${#WHEELS[@]}" ]; then
    echo "gpu_wheels.sh: expected ${#WHEELS[@]} wheels in $DEST, found $count" >&2
    exit 1
fi
echo "total: $(du -sh "$DEST" | cut -f1) in $count wheels ($DEST)"
