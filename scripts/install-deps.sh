#!/usr/bin/env bash
# Installs the Debian 12 packages matlaber needs to build and test. Idempotent: does nothing when
# everything is present. Needs root for apt-get; otherwise prints the command to run.
set -euo pipefail

PACKAGES=(
  build-essential cmake pkg-config   # compiler (gcc with OpenMP, ASan/UBSan runtimes), build
  libopenblas-dev                    # BLAS (GEMM) and LAPACK (PCA)
  libcjson-dev                       # JSON (safetensors headers, configs)
  libstb-dev                         # PNG/JPEG decoding
  libpng-dev zlib1g-dev              # PNG writing, gzip
  libutf8proc-dev                    # Unicode categories, case mapping, NFC (the CLIP tokenizer)
  libtinyexr-dev                     # OpenEXR reading and writing (environment maps, linear images)
  clang libclang-rt-14-dev           # libFuzzer target for the safetensors reader (scripts/fuzz.sh)
  chromium                           # headless browser for the viewer test (tests/cli_viewer.sh)
  blender python3-numpy              # the Blender add-on's test (tests/cli_blender.sh); its glTF importer needs numpy
  libmicrohttpd-dev                  # HTTP server of `matlaber serve` (docs/server.md); without it only serve is missing
  curl                               # the server's test (tests/cli_serve.sh) talks to it with curl
  libopenmpi-dev openmpi-bin         # MPI: several processes on one asset or many (mpirun; tests/cli_mpi.sh)
)
# node and npm (three.js for `matlaber view`, the glTF-Validator and playwright-core for the tests;
# scripts/build.sh runs npm ci in viewer/): Debian's packages only when the commands are missing, so
# that a NodeSource nodejs (which ships npm itself and conflicts with Debian's npm) is left alone.
# Optional (installed when root, never an error when missing): oneDNN for bench_gemm_onednn, the
# comparison of its bf16 matmul with the program's own kernel (docs/ops.md). Nothing else uses it.
OPTIONAL=(libdnnl-dev)
command -v node > /dev/null 2>&1 || PACKAGES+=(nodejs)
command -v npm > /dev/null 2>&1 || PACKAGES+=(npm)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

optional_missing=()
for p in "${OPTIONAL[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    optional_missing+=("$p")
  fi
done
if [ ${#optional_missing[@]} -gt 0 ]; then
  if [ "$(id -u)" -eq 0 ]; then
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${optional_missing[@]}" ||
      echo "install-deps: optional ${optional_missing[*]} not installed (only bench_gemm_onednn needs it)"
  else
    echo "install-deps: optional, for bench_gemm_onednn only: sudo apt-get install ${optional_missing[*]}"
  fi
fi

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages present"
  exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
  echo "install-deps: missing Debian packages: ${missing[*]}" >&2
  echo "install-deps: not root; run this, then the same command again:" >&2
  echo "  sudo apt-get update && sudo apt-get install -y --no-install-recommends ${missing[*]}" >&2
  exit 1
fi

echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "install-deps: done"
