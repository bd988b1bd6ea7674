#!/usr/bin/env bash
# Configures and builds matlaber. Usage: scripts/build.sh [--sanitize]
#   default     build/       Release, CUDA part when nvcc is found
#   --sanitize  build-asan/  Debug with AddressSanitizer + UndefinedBehaviorSanitizer, CPU only
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" = "--sanitize" ]; then
  dir=build-asan
  args=(-DCMAKE_BUILD_TYPE=Debug -DMLB_SANITIZE=ON -DMLB_CUDA=OFF)
else
  dir=build
  args=(-DCMAKE_BUILD_TYPE=Release)
fi
mkdir -p "$dir"
cmake -S . -B "$dir" "${args[@]}" > "$dir/configure.log" 2>&1 || { cat "$dir/configure.log"; exit 1; }
grep -E "matlaber: CUDA part" "$dir/configure.log" || true
cmake --build "$dir" -j"$(nproc)"
