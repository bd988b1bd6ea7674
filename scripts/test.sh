#!/usr/bin/env bash
# Builds and runs the test suite. Usage: scripts/test.sh [--sanitize]
# Installs missing packages first (a no-op when all are there). CTest's closing line reports
# "N% tests passed, M tests failed out of T"; tests that need ../shared/data skip without it.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh "$@"
dir=build
[ "${1:-}" = "--sanitize" ] && dir=build-asan
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=0}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
cd "$dir"
ctest --output-on-failure -j"$(nproc)"
