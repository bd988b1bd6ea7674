#!/usr/bin/env bash
# The first command on a fresh machine: installs what is missing, builds, and runs the default job
# (matlaber demo: trains the default BRDF prior and prints its evaluation).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
./build/matlaber demo
