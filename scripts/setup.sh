#!/usr/bin/env bash
# The first command on a fresh machine: installs what is missing, builds, and runs the default job
# (matlaber demo: text to 3D with the project's own model, "a gold goblet" generated and measured
# against the catalogue's truth; `matlaber demo --fit` is the image-fitting demo).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
./build/matlaber demo
