#!/usr/bin/env bash
# On a machine with an NVIDIA GPU and the CUDA toolkit: builds with the CUDA part and runs the
# GPU parity tests (CUDA kernels against the CPU code). Used through the device tool.
set -euo pipefail
cd "$(dirname "$0")/.."
nvidia-smi -L || { echo "gpu-parity: no GPU visible" >&2; exit 1; }
bash scripts/build.sh
ctest --test-dir build --output-on-failure -R cuda
