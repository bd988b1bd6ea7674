#!/usr/bin/env bash
# The CUDA parity tests (tests/test_cuda_* and test_backend_ops: CUDA kernels against the CPU code) and, with --bench,
# bench/bench_cuda, in one call on a machine with an NVIDIA GPU. docs/cuda.md.
#
#   scripts/gpu-parity.sh --fetch-debs   HERE (Debian 12, with network): downloads the -dev packages the
#                                        build needs into build-gpu-debs/ (ignored by git), for a GPU
#                                        machine that cannot install anything
#   scripts/gpu-parity.sh [--bench [--cudnn-baseline] | --bench-kernels] [--memcheck] [--pipeline]
#                                        ON THE GPU MACHINE, in the repository root: configures
#                                        build-gpu/ (CUDA on, sm_90 unless MLB_CUDA_ARCH says otherwise),
#                                        unpacks build-gpu-debs/*.deb into a private prefix when a
#                                        dependency is missing, builds the CUDA tests (and bench_cuda),
#                                        runs them and prints a table. Logs go to $OUT when set.
#                                        --memcheck runs each test under compute-sanitizer memcheck.
#                                        --bench-kernels: bench_cuda and bench_render_ops alone (no
#                                        full-size UNet/VAE benches; --bench runs all of them).
#   scripts/gpu-parity.sh --train [...]   ON THE GPU MACHINE: also builds matlaber and trains the project's
#                                        own model there (`sd train`, arguments from MLB_TRAIN_ARGS), then
#                                        samples it (`sd txt2img`); the model folder comes back as
#                                        $OUT/own-model.tar.gz (split in 15 MB parts when larger).
# Through the device tool:  run(command="bash scripts/gpu-parity.sh --bench", carry=["build-gpu-debs"])
# Exit status: 0 when every test passed, 1 when one failed or did not run, 2 for a setup error.
set -uo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
debs=$root/build-gpu-debs
PKGS=(libopenblas-dev libopenblas-pthread-dev libopenblas0-pthread libopenblas0 libgfortran5 libcjson-dev libcjson1
      libstb-dev libstb0 libutf8proc-dev libutf8proc2 libtinyexr-dev libtinyexr1d libpng-dev libpng16-16 zlib1g-dev
      pkgconf pkgconf-bin libpkgconf3)

if [ "${1:-}" = "--fetch-debs" ]; then
  mkdir -p "$debs"
  (cd "$debs" && apt-get download "${PKGS[@]}") || { echo "gpu-parity: apt-get download failed" >&2; exit 2; }
  du -sh "$debs"
  echo "gpu-parity: now run(command=\"bash scripts/gpu-parity.sh --bench\", carry=[\"build-gpu-debs\"])"
  exit 0
fi
bench=0
memcheck=0
pipeline=0
cudnn_baseline=0
train=0
for a in "$@"; do
  case $a in
    --bench) bench=1 ;;
    --bench-kernels) bench=2 ;;   # bench_cuda and bench_render_ops only
    --memcheck) memcheck=1 ;;   # every test under compute-sanitizer (out-of-bounds, races: slower)
    --pipeline) pipeline=1 ;;   # bench_pipeline with full-size random SD 1.5 on the GPU, 9 views at 512² (~2 min)
    --cudnn-baseline) cudnn_baseline=1 ;;   # with --bench: the UNet and VAE benches again with MLB_CUDNN=0
    --train) train=1 ;;   # sd train on the GPU (MLB_TRAIN_ARGS), the model folder back under $OUT
    *) echo "usage: scripts/gpu-parity.sh [--fetch-debs | [--bench [--cudnn-baseline] | --bench-kernels] [--memcheck] [--pipeline] [--train]]" >&2; exit 2 ;;
  esac
done

# Per-step logs in build-gpu/logs; the summary log (every test's output, the bench table) and the
# error table are copied to $OUT when set (the device tool brings back at most 8 files).
out=$root/build-gpu/logs
mkdir -p "$out"
log=$out/gpu-parity.log
[ -n "${OUT:-}" ] && log=$OUT/gpu-parity.log   # written in place: it comes back even if the call is cut off
finish() {
  if [ -n "${OUT:-}" ]; then
    [ -f "$out/parity-errors.txt" ] && cp "$out/parity-errors.txt" "$OUT/"
    if [ $built = 0 ]; then   # the build logs only when the build did not get through (at most 8 files come back)
      [ -f "$out/build.log" ] && cp "$out/build.log" "$OUT/"
      [ -f "$out/configure.log" ] && cp "$out/configure.log" "$OUT/"
    fi
    [ -f "$out/bench_cuda_unet.log" ] && cp "$out/bench_cuda_unet.log" "$OUT/"
    [ -f "$out/bench_cuda_vae.log" ] && cp "$out/bench_cuda_vae.log" "$OUT/"
    [ -f "$out/bench_cuda_unet_noflash.log" ] && cp "$out/bench_cuda_unet_noflash.log" "$OUT/"
    [ -f "$out/bench_pipeline.log" ] && cp "$out/bench_pipeline.log" "$OUT/"
    for f in "$out"/test_cuda_*.log "$out"/test_backend_ops.log; do grep -q "FAIL" "$f" 2> /dev/null && cp "$f" "$OUT/"; done
  fi
}
built=0
trap finish EXIT
: > "$log"
say() { echo "$@" | tee -a "$log"; }

say "gpu-parity: $(date -u '+%Y-%m-%d %H:%M UTC') on $(hostname)"
if command -v nvidia-smi > /dev/null; then
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>&1 | tee -a "$log"
else
  say "gpu-parity: nvidia-smi not found: the tests will skip (no CUDA device)"
fi
nvcc=${CUDACXX:-$(command -v nvcc || echo /usr/local/cuda/bin/nvcc)}
[ -x "$nvcc" ] || { say "gpu-parity: nvcc not found (set CUDACXX)"; exit 2; }
"$nvcc" --version | tail -1 | tee -a "$log"

# ---- dependencies: the system's when present, else the carried Debian packages in a private prefix
need_debs=0
command -v pkg-config > /dev/null || { say "gpu-parity: pkg-config missing"; need_debs=1; }
for p in openblas libcjson stb libpng zlib libutf8proc; do
  pkg-config --exists "$p" 2> /dev/null || { say "gpu-parity: $p missing"; need_debs=1; }
done
[ -e /usr/lib/x86_64-linux-gnu/libtinyexr.so ] || [ -e /usr/lib/libtinyexr.so ] || [ -e /usr/local/lib/libtinyexr.so ] \
  || { say "gpu-parity: tinyexr missing"; need_debs=1; }
if [ $need_debs = 1 ]; then
  ls "$debs"/*.deb > /dev/null 2>&1 || {
    say "gpu-parity: dependencies missing and no build-gpu-debs/: run 'bash scripts/gpu-parity.sh --fetch-debs' where apt works, then carry build-gpu-debs"
    exit 2
  }
  prefix=/tmp/mlb-deps
  rm -rf "$prefix" && mkdir -p "$prefix"
  for f in "$debs"/*.deb; do dpkg-deb -x "$f" "$prefix" || { say "gpu-parity: cannot unpack $f"; exit 2; }; done
  # .pc files say /usr: point them into the prefix, and put every folder holding one on the path
  pcdirs=$(find "$prefix" -name '*.pc' -exec sed -i "s#=/usr#=$prefix/usr#g; s# /usr/# $prefix/usr/#g" {} \; -printf '%h\n' | sort -u | tr '\n' ':')
  export PKG_CONFIG_PATH="${pcdirs}${PKG_CONFIG_PATH:-}"
  libdirs=$(find "$prefix" -name '*.so*' -printf '%h\n' | sort -u | tr '\n' ':')
  export LD_LIBRARY_PATH="${libdirs}${LD_LIBRARY_PATH:-}"
  export LIBRARY_PATH="${libdirs}${LIBRARY_PATH:-}"
  export CPATH="$prefix/usr/include:${CPATH:-}"
  command -v pkg-config > /dev/null || export PATH="$prefix/usr/bin:$PATH"
  extra_cmake=(-DCMAKE_PREFIX_PATH="$prefix/usr" -DCMAKE_LIBRARY_PATH="$prefix/usr/lib/x86_64-linux-gnu")
  say "gpu-parity: using the carried packages in $prefix"
else
  extra_cmake=()
fi

# ---- configure and build only what runs here
build=$root/build-gpu
rm -f "$build/CMakeCache.txt"   # a fresh configure: cached pkg-config paths may point at a removed prefix
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release -DMLB_CUDA=ON -DCMAKE_CUDA_COMPILER="$nvcc" \
  -DCMAKE_CUDA_ARCHITECTURES="${MLB_CUDA_ARCH:-90}" "${extra_cmake[@]}" > "$out/configure.log" 2>&1 \
  || { tail -30 "$out/configure.log"; say "gpu-parity: configure failed ($out/configure.log)"; exit 2; }
grep -E "matlaber: (CUDA part|cuDNN)" "$out/configure.log" | tee -a "$log"
grep -q "matlaber: CUDA part ON" "$out/configure.log" || { say "gpu-parity: the CUDA part is off"; exit 2; }
# test_backend_ops: every op of every CUDA table against the CPU's (its CPU part runs everywhere)
# test_text_encoder: its tiny_cuda_tables case (the encoder on the CUDA tables) skips without a GPU
tests=${MLB_GPU_TESTS:-$(cd tests && ls test_cuda_*.c test_backend_ops.c test_text_encoder.c | sed 's/\.c$//')}   # MLB_GPU_TESTS="test_cuda_x ...": only those
targets=$tests
[ $bench = 1 ] && targets="$targets bench_cuda bench_render_ops bench_cuda_unet bench_cuda_vae"
[ $bench = 2 ] && targets="$targets bench_cuda bench_render_ops"
[ $pipeline = 1 ] && targets="$targets bench_pipeline"
[ $train = 1 ] && targets="$targets matlaber"
jobs=${MLB_JOBS:-$(nproc 2> /dev/null || echo 4)}
# shellcheck disable=SC2086
cmake --build "$build" -j"$jobs" --target $targets > "$out/build.log" 2>&1 \
  || { grep -E "error" "$out/build.log" | head -30; say "gpu-parity: build failed ($out/build.log)"; exit 2; }

built=1
# ---- run: a fresh random seed per run, printed so a failure can be replayed with MLB_TEST_SEED
export MLB_TEST_SEED=${MLB_TEST_SEED:-$(( $(date +%s) % 1000000 + 1 ))}
say "gpu-parity: MLB_TEST_SEED=$MLB_TEST_SEED"
fail=0
summary=""
for t in $tests; do
  start=$(date +%s%N)
  runner=()
  if [ $memcheck = 1 ]; then
    cs=$(command -v compute-sanitizer || echo /usr/local/cuda/bin/compute-sanitizer)
    runner=("$cs" --tool memcheck --error-exitcode 9)
  fi
  (cd "$build" && MLB_CUDA_SYNC=1 timeout 600 "${runner[@]}" "./tests/$t") > "$out/$t.log" 2>&1
  rc=$?
  ms=$(( ($(date +%s%N) - start) / 1000000 ))   # bash arithmetic: the GPU image has no bc
  case $rc in
    0) status=PASS ;;
    77) status=SKIP; fail=1 ;;   # on the GPU machine a skip means the GPU was not usable
    *) status="FAIL($rc)"; fail=1 ;;
  esac
  cat "$out/$t.log" >> "$log"
  summary+=$(printf '%-24s %-9s %4d.%01d s' "$t" "$status" $((ms / 1000)) $((ms % 1000 / 100)))$'\n'
done
if [ $bench -ge 1 ]; then
  (cd "$build" && ./bench/bench_cuda) 2>&1 | tee "$out/bench_cuda.log" | tee -a "$log"
  (cd "$build" && ./bench/bench_render_ops) 2>&1 | tee "$out/bench_render_ops.log" | tee -a "$log"
fi
if [ $bench = 1 ]; then
  (cd "$build" && ./bench/bench_cuda_unet) 2>&1 | tee "$out/bench_cuda_unet.log" | tee -a "$log"
  (cd "$build" && ./bench/bench_cuda_vae) 2>&1 | tee "$out/bench_cuda_vae.log" | tee -a "$log"
  # the baseline of the fused attention kernel: every sdpa on the batched GEMMs (bench_cuda times both itself)
  say "gpu-parity: bench_cuda_unet with MLB_FLASH=0 (attention on the batched GEMMs)"
  (cd "$build" && MLB_FLASH=0 ./bench/bench_cuda_unet) 2>&1 | tee "$out/bench_cuda_unet_noflash.log" | tee -a "$log"
  if [ $cudnn_baseline = 1 ] && grep -q "matlaber: cuDNN /" "$out/configure.log"; then   # every convolution on the GEMM path
    say "gpu-parity: the same two benches with MLB_CUDNN=0 (convolutions on im2col + GEMM)"
    (cd "$build" && MLB_CUDNN=0 ./bench/bench_cuda_unet) 2>&1 | tee "$out/bench_cuda_unet_gemm.log" | tee -a "$log"
    (cd "$build" && MLB_CUDNN=0 ./bench/bench_cuda_vae) 2>&1 | tee "$out/bench_cuda_vae_gemm.log" | tee -a "$log"
  fi
fi
if [ $pipeline = 1 ]; then
  # MLB_PIPELINE_ARGS replaces the table's arguments (e.g. a --generate run: docs/cuda.md)
  # shellcheck disable=SC2086
  (cd "$build" && ./bench/bench_pipeline --sd15 --device cuda --precision "${MLB_PRECISION:-fp16}" --dir /tmp \
     ${MLB_PIPELINE_ARGS:---no-images --no-tiny --sd15-views 9 --sd15-sizes 512 --iters 1}) 2>&1 \
     | tee "$out/bench_pipeline.log" | tee -a "$log"
fi
if [ $train = 1 ]; then
  model=$build/own-model
  rm -rf "$model"
  # shellcheck disable=SC2086
  # from the repository root, so that MLB_TRAIN_ARGS's paths (--init models/matlaber-tiny) are the tree's
  (cd "$root" && timeout "${MLB_TRAIN_TIMEOUT:-420}" "$build/matlaber" --device cuda --precision "${MLB_PRECISION:-tf32}" sd train \
     -o "$model" ${MLB_TRAIN_ARGS:-}) 2>&1 | tr '\r' '\n' | grep -v '^\s*$' | awk 'NR % 20 == 1 || /train:|error|rror/' \
     | tee "$out/train.log" | tee -a "$log"
  for p in "a gold goblet" "a blue mug" "a silver vase" "a silver vase, normal map" "a red table"; do
    f=$(echo "$p" | tr ' ' '_').png
    (cd "$build" && ./matlaber --device cuda sd txt2img -m "$model" -p "$p" --size 128 --steps 30 --cfg 5 -o "$model/$f") 2>&1 | tail -1 | tee -a "$log"
  done
  if [ -n "${OUT:-}" ] && [ -d "$model" ]; then
    tar -C "$build" --exclude="own-model/train/*.safetensors" -czf "$out/own-model.tar.gz" own-model
    if [ "$(stat -c %s "$out/own-model.tar.gz")" -gt 15000000 ]; then
      split -b 15000000 -d "$out/own-model.tar.gz" "$OUT/own-model.tar.gz.part"
    else
      cp "$out/own-model.tar.gz" "$OUT/"
    fi
    cp "$out/train.log" "$OUT/"
  fi
fi
echo
echo "==== CUDA parity (seed $MLB_TEST_SEED) ===="
printf '%s' "$summary" | tee -a "$log"
grep -hE "rel-L2" "$out"/test_cuda_*.log "$out"/test_backend_ops.log > "$out/parity-errors.txt" 2> /dev/null
echo "(per-check errors: $out/parity-errors.txt; full log: $log)"
exit $fail
