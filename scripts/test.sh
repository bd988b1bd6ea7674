#!/usr/bin/env bash
# Builds and runs the test suite. Usage: scripts/test.sh [--sanitize]
# Installs missing packages first (a no-op when all are there). CTest's closing line reports
# "N% tests passed, M tests failed out of T"; tests that need ../shared/data skip without it.
set -euo pipefail
cd "$(dirname "$0")/.."
# The machine first, so that a failure names it (results may depend on the CPU's BLAS kernels).
echo "test: cpu $(grep -m1 '^model name' /proc/cpuinfo 2>/dev/null | cut -d: -f2- | sed 's/^ //')," \
     "family $(grep -m1 '^cpu family' /proc/cpuinfo 2>/dev/null | cut -d: -f2 | tr -d ' '), $(nproc) cores"
bash scripts/install-deps.sh
bash scripts/build.sh "$@"
dir=build
[ "${1:-}" = "--sanitize" ] && dir=build-asan
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=0}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
# What the program sees: CPU features and the OpenBLAS kernel family it runs (after its own choice).
[ -x "$dir/matlaber" ] && "$dir/matlaber" device | sed -n '1,3s/^/test: /p'
cd "$dir"
ctest --output-on-failure -j"$(nproc)"
