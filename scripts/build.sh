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

# The viewer's npm packages (viewer/package-lock.json: three.js, which `matlaber view` copies beside
# its page; gltf-validator and playwright-core for tests/cli_export.sh and cli_viewer.sh) into
# viewer/node_modules (ignored by git). Skipped while node_modules matches the lock file; without
# npm or network the build still succeeds and those tests report a skip.
if ! command -v npm > /dev/null 2>&1; then
  echo "build: npm not found: viewer/node_modules not installed (scripts/install-deps.sh); 'matlaber view' and the viewer tests need it"
elif [ viewer/node_modules/.package-lock.json -nt viewer/package-lock.json ]; then
  echo "build: viewer/node_modules up to date"
elif (cd viewer && npm ci --no-audit --no-fund --loglevel=error); then
  echo "build: viewer/node_modules installed (npm ci)"
else
  echo "build: npm ci in viewer/ failed (offline?): 'matlaber view' and the viewer tests will not work until it succeeds"
fi
