#!/usr/bin/env bash
# Side-by-side CPU benchmark: stable-diffusion.cpp (leejet/stable-diffusion.cpp, ggml) against
# `matlaber sd txt2img` (fp32 and bf16 GEMMs) on one SD 1.x single-file checkpoint: same machine,
# thread count, image size, CFG scale and step count, run one after the other. Prints a markdown
# table (load, text encoding, sampling, s/step, VAE decode, wall, CPU time, peak RSS) and the ratio
# matlaber / sd.cpp per row. stable-diffusion.cpp is not part of this repository: build it
# elsewhere and pass its CLI binary (sd-cli, formerly sd).
#
#   bench/compare_sdcpp.sh SDCPP_BIN CHECKPOINT TOKENIZER_DIR
#   (or set SDCPP_BIN, CKPT, TOKENIZER in the environment)
#
# A random-weight SD 1.5 checkpoint both programs load (F16, 1.07 B parameters, 2.1 GB; the time does
# not depend on the weights): build-nocuda/bench/bench_sd --latent 16 --vae 64 --single-file OUT.safetensors
# (about 2 minutes). TOKENIZER_DIR: a CLIP tokenizer folder (vocab.json + merges.txt), e.g.
# ../shared/data/clip. Results: docs/benchmarks.md.
#
# Environment (defaults in brackets):
#   STEPS [4]  THREADS [2]  SIZE [512]  CFG [7]  SEED [42]  PROMPT [a photo of a red apple on a table]
#   MATLABER [build/matlaber, else build-nocuda/matlaber, else build-cuda/matlaber]
#   PRECISIONS ["fp32 bf16"]      matlaber --precision values, one run each
#   SDCPP_FLAGS ["--eager-load --sampling-method ddim_trailing"]   always added to sd.cpp's command
#   SDCPP_EXTRA [""]               more sd.cpp flags, e.g. "--diffusion-fa" or "--type bf16"
#   SDCPP_INFO [<sd.cpp build dir>/../VERSIONS.txt]   text file printed as sd.cpp's version/build notes
#   OUT_DIR [./compare_sdcpp.<date>]   logs, /usr/bin/time reports and images
#   SKIP_SDCPP=1 / SKIP_MATLABER=1 skip one side (its table cells read n/a)
#
# How each number is derived (every output line of both programs is stamped with bash's
# $EPOCHREALTIME as it arrives; the processes run under /usr/bin/time -v):
#   load, own log     sd.cpp: sum of "loading tensors completed, taking X s" (with --eager-load all
#                     tensors are read while the context is created); matlaber: "model: ... (X s)".
#   launch -> ready   stamp of the first line after loading (sd.cpp "generate_image WxH", matlaber
#                     "model: ...") minus the stamp taken just before launching the process.
#   text encode       sd.cpp: "get_learned_condition completed, taking X s" (cond + uncond prompt);
#                     matlaber: "prompts encoded (X s)" (older builds logged nothing for it: then
#                     stamp(final progress line) - sampling - stamp(model line)).
#   sampling          sd.cpp: "sampling completed, taking X s"; matlaber: "took D" of the final
#                     "txt2img: N/N (100%) ..." progress line (0.1 s resolution under 60 s, 1 s above).
#   s/step            sampling / STEPS (each step: one cond + one uncond UNet pass since CFG != 1;
#                     sd.cpp runs them as two batch-1 passes, matlaber as one batch-2 pass).
#   VAE decode        sd.cpp: "decode_first_stage completed, taking X s"; matlaber: "latent decoded (X s)"
#                     (older builds: stamp("wrote ...") - stamp(final progress line), decode + PNG write).
#   wall, CPU, RSS    /usr/bin/time -v: elapsed wall clock, user + system seconds, maximum resident set.
# The checkpoint is read once (cat > /dev/null) before each run so every run starts from a warm page cache.
set -u -o pipefail
export LC_ALL=C

usage() {
    sed -n '2,/^set -u/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'
}
die() { echo "compare_sdcpp.sh: $*" >&2; exit 2; }

case "${1:-}" in -h|--help) usage; exit 0 ;; esac
[ $# -eq 0 ] || [ $# -eq 3 ] || { usage >&2; die "expected 0 or 3 arguments (SDCPP_BIN CHECKPOINT TOKENIZER_DIR), got $#"; }
if [ $# -eq 3 ]; then SDCPP_BIN=$1; CKPT=$2; TOKENIZER=$3; fi
REPO=$(cd "$(dirname "$0")/.." && pwd)
STEPS=${STEPS:-4}; THREADS=${THREADS:-2}; SIZE=${SIZE:-512}; CFG=${CFG:-7}; SEED=${SEED:-42}
PROMPT=${PROMPT:-a photo of a red apple on a table}
PRECISIONS=${PRECISIONS:-fp32 bf16}
SDCPP_FLAGS=${SDCPP_FLAGS:---eager-load --sampling-method ddim_trailing}
SDCPP_EXTRA=${SDCPP_EXTRA:-}
SKIP_SDCPP=${SKIP_SDCPP:-0}; SKIP_MATLABER=${SKIP_MATLABER:-0}
if [ -z "${MATLABER:-}" ]; then
    for c in "$REPO/build/matlaber" "$REPO/build-nocuda/matlaber" "$REPO/build-cuda/matlaber"; do
        [ -x "$c" ] && { MATLABER=$c; break; }
    done
fi

[ -n "${CKPT:-}" ] || { usage >&2; die "no checkpoint: pass it as the 2nd argument or set CKPT"; }
[ -f "$CKPT" ] || die "checkpoint not found: $CKPT"
if [ "$SKIP_SDCPP" != 1 ]; then
    [ -n "${SDCPP_BIN:-}" ] || { usage >&2; die "no sd.cpp binary: pass it as the 1st argument or set SDCPP_BIN"; }
    [ -x "$SDCPP_BIN" ] || die "sd.cpp binary not found or not executable: $SDCPP_BIN"
fi
if [ "$SKIP_MATLABER" != 1 ]; then
    [ -n "${TOKENIZER:-}" ] || { usage >&2; die "no tokenizer: pass the CLIP tokenizer folder as the 3rd argument or set TOKENIZER"; }
    [ -e "$TOKENIZER" ] || die "tokenizer folder not found: $TOKENIZER"
    if [ -z "${MATLABER:-}" ] || [ ! -x "$MATLABER" ]; then
        die "matlaber binary not found (looked in $REPO/build*/matlaber; set MATLABER)"
    fi
fi
[ -x /usr/bin/time ] || die "/usr/bin/time is missing (Debian: apt-get install time)"
for n in "$STEPS" "$THREADS" "$SIZE" "$SEED"; do
    [[ $n =~ ^[0-9]+$ ]] || die "STEPS, THREADS, SIZE and SEED must be non-negative integers"
done
[ $((SIZE % 64)) -eq 0 ] || die "SIZE must be a multiple of 64"
[ -n "${EPOCHREALTIME:-}" ] || die "needs bash >= 5 (\$EPOCHREALTIME)"

STAMP=$(date -u +%Y%m%d-%H%M%S)
OUT_DIR=${OUT_DIR:-./compare_sdcpp.$STAMP}
mkdir -p "$OUT_DIR" || die "cannot create $OUT_DIR"

# ---- helpers ----------------------------------------------------------------------------------------
stamp_lines() {   # prefix each line with the time it arrived
    local line
    while IFS= read -r line || [ -n "$line" ]; do printf '%s\t%s\n' "$EPOCHREALTIME" "$line"; done
}

# run NAME CMD...: runs CMD under /usr/bin/time -v, output stamped into $OUT_DIR/NAME.log
run() {
    local name=$1; shift
    cat "$CKPT" > /dev/null
    local q
    q=$(printf '%q ' "$@")
    echo "== $name: $q" >&2
    printf '%s\n' "${q% }" > "$OUT_DIR/$name.cmd"
    local t0=$EPOCHREALTIME
    /usr/bin/time -v -o "$OUT_DIR/$name.time" "$@" 2>&1 | stamp_lines > "$OUT_DIR/$name.log"
    local rc=${PIPESTATUS[0]}
    echo "$t0" > "$OUT_DIR/$name.t0"
    echo "$rc" > "$OUT_DIR/$name.rc"
    if [ "$rc" -ne 0 ]; then
        echo "compare_sdcpp.sh: $name failed (exit $rc); last lines of $OUT_DIR/$name.log:" >&2
        tail -n 15 "$OUT_DIR/$name.log" | cut -f2- | tr '\r' '\n' | tail -n 15 >&2
    fi
    return 0
}

# time_fields NAME -> "wall_s cpu_s rss_mb" from the /usr/bin/time -v report
time_fields() {
    awk -F': ' '
        /Elapsed \(wall clock\) time/ { n = split($NF, p, ":"); w = 0; for (i = 1; i <= n; i++) w = w * 60 + p[i] }
        /User time \(seconds\)/ { u = $NF }
        /System time \(seconds\)/ { s = $NF }
        /Maximum resident set size/ { r = $NF / 1024 }
        END { if (w == "") print "na na na"; else printf "%.2f %.2f %.0f\n", w, u + s, r }' "$OUT_DIR/$1.time" 2>/dev/null \
        || echo "na na na"
}

# sdcpp_fields NAME -> "load ready text sampling decode"
sdcpp_fields() {
    awk -F'\t' -v t0="$(cat "$OUT_DIR/$1.t0")" '
        function val(s,   a) { if (match(s, /taking [0-9.]+ ?s/)) { a = substr(s, RSTART + 7, RLENGTH - 7); sub(/ ?s$/, "", a); return a + 0 } return "" }
        { gsub(/\r/, "\n", $2) }
        $2 ~ /loading tensors completed, taking/ { load += val($2); hl = 1 }
        $2 ~ /generate_image [0-9]+x[0-9]+/ && ready == "" { ready = $1 - t0 }
        $2 ~ /get_learned_condition completed, taking/ { text += val($2); ht = 1 }
        $2 ~ /- sampling completed, taking/ { smp += val($2); hs = 1 }
        $2 ~ /decode_first_stage completed, taking/ { dec += val($2); hd = 1 }
        END {
            printf "%s %s %s %s %s\n", hl ? sprintf("%.2f", load) : "na", ready == "" ? "na" : sprintf("%.2f", ready),
                ht ? sprintf("%.2f", text) : "na", hs ? sprintf("%.2f", smp) : "na", hd ? sprintf("%.2f", dec) : "na"
        }' "$OUT_DIR/$1.log"
}

# matlaber_fields NAME -> "load ready text sampling decode"
matlaber_fields() {
    awk -F'\t' -v t0="$(cat "$OUT_DIR/$1.t0")" '
        function dur(s,   h, m, x) {   # 12.3s | 4m05s | 1h02m (mlb_format_duration)
            if (s ~ /^[0-9.]+s$/) { sub(/s$/, "", s); return s + 0 }
            if (s ~ /^[0-9]+m[0-9]+s$/) { split(s, x, /[ms]/); return x[1] * 60 + x[2] }
            if (s ~ /^[0-9]+h[0-9]+m$/) { split(s, x, /[hm]/); return x[1] * 3600 + x[2] * 60 }
            return ""
        }
        $2 ~ /^model: / && tm == "" {
            tm = $1
            if (match($2, /\([0-9.]+s\)$/)) load = substr($2, RSTART + 1, RLENGTH - 3) + 0
        }
        $2 ~ /^txt2img: [0-9]+\/[0-9]+ \(100%\).* took / {
            tp = $1; s = $2; sub(/.* took /, "", s); sub(/,.*/, "", s); smp = dur(s)
        }
        $2 ~ /^wrote / { tw = $1 }
        # newer builds log both stages: "prompts encoded (X s)", "latent decoded (X s)"
        $2 ~ /^prompts encoded \([0-9.]+s\)$/ { s = $2; gsub(/^.*\(|s\)$/, "", s); txt = s + 0 }
        $2 ~ /^latent decoded \([0-9.]+s\)$/ { s = $2; gsub(/^.*\(|s\)$/, "", s); dec = s + 0 }
        END {
            if (txt == "" && tm != "" && tp != "" && smp != "") txt = tp - smp - tm
            if (dec == "" && tp != "" && tw != "") dec = tw - tp
            printf "%s %s %s %s %s\n", load == "" ? "na" : sprintf("%.2f", load), tm == "" ? "na" : sprintf("%.2f", tm - t0),
                txt == "" ? "na" : sprintf("%.2f", txt),
                smp == "" ? "na" : sprintf("%.2f", smp), dec == "" ? "na" : sprintf("%.2f", dec)
        }' "$OUT_DIR/$1.log"
}

# ---- runs ---------------------------------------------------------------------------------------------
LOAD_BEFORE=$(cut -d' ' -f1-3 /proc/loadavg)
names=()
if [ "$SKIP_SDCPP" != 1 ]; then
    # shellcheck disable=SC2086   # SDCPP_FLAGS / SDCPP_EXTRA are word lists on purpose
    run sdcpp "$SDCPP_BIN" -v -m "$CKPT" -p "$PROMPT" -n "" -W "$SIZE" -H "$SIZE" --steps "$STEPS" --cfg-scale "$CFG" \
        -s "$SEED" -t "$THREADS" $SDCPP_FLAGS $SDCPP_EXTRA -o "$OUT_DIR/sdcpp.png"
    names+=(sdcpp)
fi
if [ "$SKIP_MATLABER" != 1 ]; then
    for p in $PRECISIONS; do
        run "matlaber_$p" "$MATLABER" --threads "$THREADS" --device cpu --precision "$p" sd txt2img -m "$CKPT" \
            --tokenizer "$TOKENIZER" -p "$PROMPT" --size "$SIZE" --steps "$STEPS" --cfg "$CFG" --seed "$SEED" \
            -o "$OUT_DIR/matlaber_$p.png"
        names+=("matlaber_$p")
    done
fi
LOAD_AFTER=$(cut -d' ' -f1-3 /proc/loadavg)

# ---- collect ------------------------------------------------------------------------------------------
# per run: load ready text sampling s/step decode wall cpu rss  (na where missing or failed)
declare -A V
for n in "${names[@]}"; do
    if [ "$(cat "$OUT_DIR/$n.rc")" != 0 ]; then f="na na na na na"; t="na na na"
    elif [ "$n" = sdcpp ]; then f=$(sdcpp_fields "$n"); t=$(time_fields "$n")
    else f=$(matlaber_fields "$n"); t=$(time_fields "$n"); fi
    read -r a b c d e <<< "$f"
    read -r w u r <<< "$t"
    ps=$(awk -v s="$d" -v n="$STEPS" 'BEGIN { if (s == "na" || n == 0) print "na"; else printf "%.2f", s / n }')
    V[$n]="$a $b $c $d $ps $e $w $u $r"
done

# ---- report -------------------------------------------------------------------------------------------
cpu_model=$(awk -F': ' '/^model name/ { print $2; exit }' /proc/cpuinfo)
cpu_fam=$(awk -F': ' '/^cpu family/ { print $2; exit }' /proc/cpuinfo)
cpu_mod=$(awk -F': ' '/^model[ \t]*:/ { print $2; exit }' /proc/cpuinfo)
cpu_flags=$(awk -F': ' '/^flags/ { n = split($2, f, " "); for (i = 1; i <= n; i++)
    if (f[i] ~ /^(avx2|fma|f16c|avx512f|avx512_bf16|avx512_fp16|avx512_vnni|amx_bf16|amx_tile)$/) printf "%s ", f[i]; exit }' /proc/cpuinfo)
ncpu=$(nproc)
mem=$(awk '/MemTotal/ { printf "%.1f GiB", $2 / 1048576 }' /proc/meminfo)

echo
echo "## matlaber vs stable-diffusion.cpp, CPU, SD 1.x txt2img"
echo
echo "- date: $(date -u '+%Y-%m-%d %H:%M:%S UTC'); host: $(uname -sr)"
echo "- CPU: $cpu_model (family $cpu_fam, model $cpu_mod), $ncpu logical CPUs, $mem RAM; flags: $cpu_flags"
echo "- load average (1/5/15 min) before: $LOAD_BEFORE; after: $LOAD_AFTER"
echo "- checkpoint: $CKPT ($(du -m "$CKPT" | cut -f1) MB)"
echo "- settings: ${SIZE}x${SIZE}, $STEPS steps, CFG $CFG (cond + uncond UNet pass per step), seed $SEED, $THREADS threads, prompt \"$PROMPT\""
env_omp=$(env | grep -E '^(OMP_|GOMP_|OPENBLAS_|MATLABER_)' | tr '\n' ' ')
echo "- environment: ${env_omp:-no OMP_/GOMP_/OPENBLAS_/MATLABER_ variables set}"
if [ "$SKIP_SDCPP" != 1 ]; then
    ver=$(cut -f2- "$OUT_DIR/sdcpp.log" | grep -m1 -o 'stable-diffusion.cpp version.*')
    sysinfo=$(cut -f2- "$OUT_DIR/sdcpp.log" | grep -m1 -A1 'System Info' | tail -n1 | tr -s ' ' | sed 's/^ //; s/ | *$//')
    echo "- sd.cpp: $SDCPP_BIN; ${ver:-version not in its log}; ggml CPU features: ${sysinfo:-?}"
    echo "- sd.cpp command: $(cat "$OUT_DIR/sdcpp.cmd")"
    bdir=$(cd "$(dirname "$SDCPP_BIN")/.." 2>/dev/null && pwd)
    for cache in "$bdir/CMakeCache.txt" "$(dirname "$SDCPP_BIN")/CMakeCache.txt"; do
        if [ -f "$cache" ]; then
            flags=$(grep -E '^(CMAKE_BUILD_TYPE|CMAKE_C_COMPILER|CMAKE_C_FLAGS|CMAKE_CXX_FLAGS|GGML_NATIVE|GGML_BLAS|GGML_BLAS_VENDOR|GGML_OPENMP|GGML_AVX512[A-Z0-9_]*|GGML_CPU_ALL_VARIANTS|SD_(WEBP|WEBM|CUDA|VULKAN|BUILD_SHARED_LIBS|USE_SYSTEM_GGML)):' "$cache" \
                | sed 's/:[A-Z]*=/=/' | tr '\n' ' ')
            echo "- sd.cpp build ($cache): $flags"
            fm=$(dirname "$cache")/ggml/src/CMakeFiles/ggml-cpu.dir/flags.make
            if [ -f "$fm" ]; then
                echo "- ggml-cpu C flags: $(grep -m1 '^C_FLAGS' "$fm" | sed 's/^C_FLAGS = //' | tr ' ' '\n' | grep -E '^-(O|march|mtune|m[a-z0-9]|f(openmp|fast))' | tr '\n' ' ')"
            fi
            break
        fi
    done
    info=${SDCPP_INFO:-$bdir/../VERSIONS.txt}
    if [ -f "$info" ]; then echo "- sd.cpp notes ($info):"; sed 's/^/    /' "$info"; fi
fi
if [ "$SKIP_MATLABER" != 1 ]; then
    echo "- matlaber: $MATLABER ($("$MATLABER" version 2>/dev/null); git $(git -C "$REPO" rev-parse --short HEAD 2>/dev/null || echo '?'))"
    "$MATLABER" device 2>/dev/null | grep -E '^(cpu|blas)' | sed 's/^/    /'
    echo "- matlaber command ($(echo "$PRECISIONS" | tr ' ' '/')): $(cat "$OUT_DIR/matlaber_${PRECISIONS%% *}.cmd")"
fi
echo "- logs: $OUT_DIR"
echo

rows=("model load, s (own log)" "launch -> model ready, s" "text encode (2 prompts), s" "sampling, s" "s / step"
      "VAE decode, s" "total wall, s" "CPU time user+sys, s" "peak RSS, MB")
hdr="| | sd.cpp"; sep="|---|--:"
for p in $PRECISIONS; do hdr+=" | matlaber $p"; sep+="|--:"; done
for p in $PRECISIONS; do hdr+=" | $p / sd.cpp"; sep+="|--:"; done
echo "$hdr |"; echo "$sep|"
for i in "${!rows[@]}"; do
    sv=na
    [ -n "${V[sdcpp]:-}" ] && sv=$(echo "${V[sdcpp]}" | cut -d' ' -f$((i + 1)))
    line="| ${rows[$i]} | $sv"
    ratios=""
    for p in $PRECISIONS; do
        mv=na
        [ -n "${V[matlaber_$p]:-}" ] && mv=$(echo "${V[matlaber_$p]}" | cut -d' ' -f$((i + 1)))
        line+=" | $mv"
        ratios+=" | $(awk -v a="$mv" -v b="$sv" 'BEGIN { if (a == "na" || b == "na" || b + 0 <= 0) print "na"; else printf "%.2f", a / b }')"
    done
    echo "$line$ratios |"
done
echo
echo "Ratios below 1: matlaber takes less time / memory than sd.cpp. Numbers: see the header of $0."
echo "matlaber text encode and VAE decode: its \"prompts encoded\" and \"latent decoded\" lines (or, from builds"
echo "that lack them, the stamps around them: see the header of bench/compare_sdcpp.sh)."
fail=0
for n in "${names[@]}"; do [ "$(cat "$OUT_DIR/$n.rc")" = 0 ] || { echo "**$n failed (exit $(cat "$OUT_DIR/$n.rc")): $OUT_DIR/$n.log**"; fail=1; }; done
exit $fail
