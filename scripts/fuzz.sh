#!/usr/bin/env bash
# Fuzz the safetensors reader with libFuzzer + AddressSanitizer + UndefinedBehaviorSanitizer.
#   scripts/fuzz.sh [SECONDS]      (default 600)
# Builds fuzz/corpus-run/fuzz_safetensors with clang straight from the sources it needs (not part
# of the CMake build), writes seed files with the same source built as a seeder, then fuzzes for
# SECONDS. The corpus grows in fuzz/corpus-run/corpus (gitignored, kept between runs); crashes
# land in fuzz/crash-* (gitignored). The log is fuzz/corpus-run/fuzz.log. Exit status 0 = no crash.
set -euo pipefail
secs="${1:-600}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
run=fuzz/corpus-run
mkdir -p "$run/corpus"

cc=""
for c in clang-14 clang; do
  if command -v "$c" >/dev/null 2>&1; then cc="$c"; break; fi
done
if [ -z "$cc" ]; then echo "fuzz.sh: clang not found (apt-get install clang-14 libclang-rt-14-dev)" >&2; exit 1; fi

srcs="src/io/safetensors.c src/io/half.c src/core/error.c src/core/fileio.c"
flags="-std=c11 -D_GNU_SOURCE -g -O1 -Iinclude -fno-omit-frame-pointer"
san="-fsanitize=address,undefined -fno-sanitize-recover=all"

echo "fuzz.sh: building with $cc"
# shellcheck disable=SC2086
"$cc" $flags $san -fsanitize=fuzzer fuzz/fuzz_safetensors.c $srcs -lcjson -lm -o "$run/fuzz_safetensors"
# shellcheck disable=SC2086
"$cc" $flags $san -DMLB_FUZZ_SEED fuzz/fuzz_safetensors.c $srcs -lcjson -lm -o "$run/seed_safetensors"
"$run/seed_safetensors" "$run/corpus"
echo "fuzz.sh: $(find "$run/corpus" -type f | wc -l) files in the corpus"

# Tokens that steer mutations towards the header grammar.
cat > "$run/safetensors.dict" <<'EOF'
"__metadata__"
"dtype"
"shape"
"data_offsets"
"\"F64\""
"\"F32\""
"\"F16\""
"\"BF16\""
"\"I64\""
"\"I32\""
"\"I16\""
"\"I8\""
"\"U8\""
"\"U16\""
"\"U32\""
"\"U64\""
"\"BOOL\""
"\"F8_E4M3\""
"\"F8_E5M2\""
"9007199254740992"
"9007199254740993"
"1e300"
"-0"
"\\u0000"
"\\ud800"
"\xed\xa0\x80"
"\xf4\x90\x80\x80"
"\xc0\xaf"
"[0,0]"
"[]"
"{}"
EOF

before=$(ls fuzz/crash-* fuzz/leak-* fuzz/timeout-* fuzz/oom-* 2>/dev/null | wc -l || true)
start=$(date +%s)
set +e
"$run/fuzz_safetensors" -max_total_time="$secs" -max_len=4096 -timeout=10 -rss_limit_mb=2048 \
  -dict="$run/safetensors.dict" -artifact_prefix=fuzz/ -print_final_stats=1 "$run/corpus" >"$run/fuzz.log" 2>&1
rc=$?
set -e
end=$(date +%s)
after=$(ls fuzz/crash-* fuzz/leak-* fuzz/timeout-* fuzz/oom-* 2>/dev/null | wc -l || true)

echo "fuzz.sh: libFuzzer exit status $rc after $((end - start)) s; last lines of $run/fuzz.log:"
grep -E '^(#[0-9]+|Done|stat::|==[0-9]+==ERROR|SUMMARY)' "$run/fuzz.log" | tail -n 12
echo "fuzz.sh: new crash/leak/timeout files: $((after - before))"
[ "$rc" -eq 0 ] && [ "$after" -eq "$before" ]
