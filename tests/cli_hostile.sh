#!/usr/bin/env bash
# Hostile input to the command line (docs/files.md, "What each input may be"): each case ends in a
# clear error naming the input and the problem, or in correct output, with nothing left behind.
set -u
M=${1:?usage: cli_hostile.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
Q="$M --log-level warn"

# --prompts: the command line's words and a line's options go whole into each prompt's generate,
# however many (340 words before and 32 option pairs on the line once overran a fixed vector on the
# stack). The last word, an invalid --res, must reach generate: it fails at once, naming it.
many=$(printf -- '--seed 1 %.0s' $(seq 170))
printf -- '--seed 2 %.0s' $(seq 32) > "$T/p.txt"
echo 'a gold goblet' >> "$T/p.txt"
expect 1 "--prompts: 340 words on the command line, 32 option pairs on the line" -- $Q generate $many --res 7 --prompts "$T/p.txt" -o "$T/many"
err_has "the command line's last word reached generate" "res: expected a multiple of 8"
grep -q '"status":[[:space:]]*"failed"' "$T/many/summary.json" && ok "summary.json: the prompt failed" || bad "summary.json: not failed"
[ -e "$T/many/.claims" ] && bad "claims left behind" || ok "no claims left behind"

# ---- 2. hangs ----
# One triangle given 400 times in one OBJ polygon (2.4 KB: 400 copies and 798 slivers once kept the
# UV atlas busy for minutes, at paint's end and in export): painted, its asset written, exported.
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf' > "$T/rep.obj"
for i in $(seq 400); do printf ' 1 2 3'; done >> "$T/rep.obj"
echo >> "$T/rep.obj"
small="--res 32 --views 2 --appearance-iters 1 --preview-every 0 --set material_start=0 --export-texture 256"
expect 0 "paint: one triangle given 400 times" -- timeout 900 $Q paint --mesh "$T/rep.obj" -p "a red cube" $small -o "$T/rep"
[ -s "$T/rep/final/asset.glb" ] && ok "its asset written" || bad "no final/asset.glb"
expect 0 "export of that run" -- timeout 300 $M export "$T/rep" --texture-size 256 -o "$T/rep.glb"
err_has "two charts: the triangle and its slivers" "UV atlas: 2 charts"

# A named pipe wherever a file is read: refused at once, never waited on (opening a pipe for reading
# blocks until a writer comes); `timeout` turns a hang into exit 124.
mkfifo "$T/pipe.obj" "$T/pipe.txt" "$T/pipe.bin"
printf '{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}],"bufferViews":[{"buffer":0,"byteLength":36}],"buffers":[{"byteLength":36,"uri":"pipe.bin"}]}' > "$T/piped.gltf"
mkdir -p "$T/piperun"
mkfifo "$T/piperun/config.json"
pipe_refused() {   # NAME RUN_DIR_OR_- command...
  local name=$1 dir=$2; shift 2
  expect 1 "$name: refused" -- timeout 20 "$@"
  err_has "$name: the pipe named" "not a regular file (a named pipe)"
  [ "$dir" = - ] || { [ -e "$dir" ] && bad "$name: $dir left behind" || ok "$name: nothing written"; }
}
pipe_refused "paint --mesh a pipe" "$T/p1" $Q paint --mesh "$T/pipe.obj" -p "a red cube" -o "$T/p1"
pipe_refused "a .gltf whose buffer is a pipe" "$T/p2" $Q paint --mesh "$T/piped.gltf" -p "a red cube" -o "$T/p2"
pipe_refused "generate --prompts a pipe" "$T/p3" $Q generate --prompts "$T/pipe.txt" -o "$T/p3"
pipe_refused "a run whose config.json is a pipe: generate --resume" - $Q generate --resume "$T/piperun"
pipe_refused "a run whose config.json is a pipe: export" - $Q export "$T/piperun" -o "$T/p5.glb"
[ -e "$T/p5.glb" ] && bad "export: p5.glb left behind" || ok "export: nothing written"

finish
