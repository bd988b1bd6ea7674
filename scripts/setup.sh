#!/usr/bin/env bash
# The first command on a fresh machine: installs what is missing, builds, and runs the default job
# (matlaber demo: a procedural gold-and-glaze goblet fitted from an ellipsoid through both stages of
# the pipeline, with image guidance, and measured; under 2 minutes on 2 cores).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
./build/matlaber demo
