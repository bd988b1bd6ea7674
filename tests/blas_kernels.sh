#!/usr/bin/env bash
# The thread-count independence of the results must not rest on the BLAS kernels this machine
# happens to pick (Haswell kernels on an AMD EPYC once broke it). This runs the test programs
# that compare 1, 2 (and 3) threads bitwise again under every OpenBLAS kernel family this CPU can
# execute, forced through $OPENBLAS_CORETYPE. Usage: blas_kernels.sh TESTS_DIR [quick]
# (quick: only the GEMM-level programs, for the sanitizer build, which runs every program anyway).
set -uo pipefail
dir=${1:?usage: blas_kernels.sh TESTS_DIR [quick]}
flags=$(grep -m1 '^flags' /proc/cpuinfo 2>/dev/null || true)
if [ -z "$flags" ] || [ "$(uname -m)" != x86_64 ]; then echo "skip: not an x86-64 Linux machine"; exit 77; fi
has() { for f in "$@"; do [[ " ${flags#*:} " == *" $f "* ]] || return 1; done; }

families=(Prescott)
has avx2 fma && families+=(Haswell Zen)
has avx512f avx512bw avx512vl avx512dq avx512cd && families+=(SkylakeX)
has avx512f avx512bw avx512vl avx512dq avx512cd avx512_bf16 && families+=(Cooperlake)
programs=(test_gemm test_ops test_conv_ops test_sd_tiny test_vae test_appearance test_hashgrid)
[ "${2:-}" = quick ] && programs=(test_gemm test_ops test_conv_ops)

fail=0 pass=0
for fam in "${families[@]}"; do
  for p in "${programs[@]}"; do
    out=$(OPENBLAS_CORETYPE=$fam OPENBLAS_VERBOSE=2 "$dir/$p" 2>&1)
    rc=$?
    core=$(grep -m1 '^Core:' <<< "$out" | awk '{print $2}')
    if [ "$rc" -ne 0 ] && [ "$rc" -ne 77 ]; then
      echo "FAIL $p under $fam kernels (OpenBLAS reports Core: ${core:-?})"
      grep -E 'FAIL|failed' <<< "$out" | head -10
      fail=$((fail + 1))
    elif [ -n "$core" ] && [ "${core,,}" != "${fam,,}" ]; then
      echo "FAIL $p: asked OpenBLAS for $fam kernels, it used ${core}"
      fail=$((fail + 1))
    else
      pass=$((pass + 1))
    fi
  done
  echo "kernels $fam: ${#programs[@]} programs run"
done
echo "$pass passed, $fail failed"
[ "$fail" -eq 0 ]
