#!/usr/bin/env bash
# Fuzz a file reader with libFuzzer + AddressSanitizer + UndefinedBehaviorSanitizer.
#   scripts/fuzz.sh [safetensors|obj|gltf|prompts|config] [SECONDS]      (default: safetensors, 600 s)
#   MLB_FUZZ_RUNS=N stops after N executions instead (and SECONDS, if given, still bounds the time)
# Builds fuzz/corpus-run[-obj]/fuzz_TARGET with clang straight from the sources it needs (not part
# of the CMake build), writes seed files with the same source built as a seeder, then fuzzes for
# SECONDS. The corpus grows in fuzz/corpus-run/corpus (gitignored, kept between runs); crashes
# land in fuzz/crash-* (gitignored). The log is fuzz/corpus-run/fuzz.log. Exit status 0 = no crash.
set -euo pipefail
target=safetensors
case "${1:-}" in safetensors|obj|gltf|prompts|config) target="$1"; shift ;; esac
secs="${1:-600}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
run=fuzz/corpus-run
[ "$target" = obj ] && run=fuzz/corpus-run-obj
[ "$target" = gltf ] && run=fuzz/corpus-run-gltf
[ "$target" = prompts ] && run=fuzz/corpus-run-prompts
[ "$target" = config ] && run=fuzz/corpus-run-config
mkdir -p "$run/corpus"

cc=""
for c in clang-14 clang; do
  if command -v "$c" >/dev/null 2>&1; then cc="$c"; break; fi
done
if [ -z "$cc" ]; then echo "fuzz.sh: clang not found (apt-get install clang-14 libclang-rt-14-dev)" >&2; exit 1; fi

if [ "$target" = obj ]; then
  srcs="src/io/obj.c src/mesh/mesh.c src/core/error.c src/core/fileio.c"; libs="-lm"
elif [ "$target" = gltf ]; then   # the exporter too, for the seeder's .glb
  srcs="src/io/gltf_read.c src/export/gltf.c src/mesh/mesh.c src/mesh/primitives.c src/core/error.c src/core/fileio.c src/core/json_why.c"
  libs="-lcjson -lpng -lm"
elif [ "$target" = prompts ]; then   # the tokenizer's UTF-8 reader checks the lines
  srcs="src/pipeline/prompts.c src/diffusion/tokenizer_text.c src/core/error.c"; libs="-lutf8proc -lm"
elif [ "$target" = config ]; then
  srcs="src/pipeline/pipeline_config.c src/pipeline/material_mode.c src/core/precision.c src/core/json_why.c src/core/error.c src/core/fileio.c"
  libs="-lcjson -lm"
else
  srcs="src/io/safetensors.c src/io/half.c src/core/error.c src/core/fileio.c"; libs="-lcjson -lm"
fi
flags="-std=c11 -D_GNU_SOURCE -g -O1 -Iinclude -Isrc -fno-omit-frame-pointer"
san="-fsanitize=address,undefined -fno-sanitize-recover=all"

echo "fuzz.sh: building with $cc"
# shellcheck disable=SC2086
"$cc" $flags $san -fsanitize=fuzzer "fuzz/fuzz_$target.c" $srcs $libs -o "$run/fuzz_$target"
# shellcheck disable=SC2086
"$cc" $flags $san -DMLB_FUZZ_SEED "fuzz/fuzz_$target.c" $srcs $libs -o "$run/seed_$target"
"$run/seed_$target" "$run/corpus"
echo "fuzz.sh: $(find "$run/corpus" -type f | wc -l) files in the corpus"

# Tokens that steer mutations towards the header grammar.
if [ "$target" = gltf ]; then
  printf '%s\n' '"glTF"' '"JSON"' '"BIN"' '"accessors"' '"bufferView"' '"bufferViews"' '"byteOffset"' '"byteLength"' \
    '"byteStride"' '"componentType"' '"count"' '"VEC3"' '"SCALAR"' '"POSITION"' '"NORMAL"' '"TEXCOORD_0"' '"indices"' \
    '"mode"' '"nodes"' '"children"' '"matrix"' '"scale"' '"scenes"' '"meshes"' '"primitives"' '"buffers"' '"uri"' \
    '"5126"' '"5125"' '"5123"' '"5121"' '"4294967295"' '"1e308"' '"-1"' '"data:;base64,"' > "$run/$target.dict"
elif [ "$target" = prompts ]; then
  printf '%s\n' '"--"' '"--name "' '"--seed "' '"--init="' '"--fixed-env "' '"\x0d"' '"\x0a"' '"\x0d\x0a"' '"#"' \
    '"\x00"' '"\xef\xbb\xbf"' '"\xc3\xa9"' '"\xed\xa0\x80"' '"\xf4\x90\x80\x80"' '"\x09"' > "$run/$target.dict"
elif [ "$target" = config ]; then
  printf '%s\n' '"\"format\""' '"\"matlaber-run\""' '"\"envs\""' '"\"seed\""' '"\"18446744073709551616\""' '"\"paint_mesh\""' \
    '"\"latent_size\""' '"\"geometry_lr\""' '"1e308"' '"-0"' '"\\u0000"' '"[[[[["' '"\"init\""' '"\"auto:\""' \
    '"\"precision\""' '"\"bf16\""' '"\"material\""' '"\"direct\""' > "$run/$target.dict"
elif [ "$target" = obj ]; then
  printf '%s\n' '"v "' '"vt "' '"vn "' '"f "' '"/"' '"//"' '"-1"' '"1e38"' '"nan"' '"# "' '"mtllib "' > "$run/$target.dict"
else
cat > "$run/$target.dict" <<'EOF'
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
fi

before=$(ls fuzz/crash-* fuzz/leak-* fuzz/timeout-* fuzz/oom-* 2>/dev/null | wc -l || true)
start=$(date +%s)
set +e
runs=()
[ -n "${MLB_FUZZ_RUNS:-}" ] && runs=(-runs="$MLB_FUZZ_RUNS")
"$run/fuzz_$target" -max_total_time="$secs" "${runs[@]}" -max_len=4096 -timeout=10 -rss_limit_mb=2048 \
  -dict="$run/$target.dict" -artifact_prefix=fuzz/ -print_final_stats=1 "$run/corpus" >"$run/fuzz.log" 2>&1
rc=$?
set -e
end=$(date +%s)
after=$(ls fuzz/crash-* fuzz/leak-* fuzz/timeout-* fuzz/oom-* 2>/dev/null | wc -l || true)

echo "fuzz.sh: libFuzzer exit status $rc after $((end - start)) s; last lines of $run/fuzz.log:"
grep -E '^(#[0-9]+|Done|stat::|==[0-9]+==ERROR|SUMMARY)' "$run/fuzz.log" | tail -n 12
echo "fuzz.sh: new crash/leak/timeout files: $((after - before))"
[ "$rc" -eq 0 ] && [ "$after" -eq "$before" ]
