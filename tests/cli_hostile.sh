#!/usr/bin/env bash
# Hostile input to the command line (docs/files.md, "What each input may be"): each case ends in a
# clear error naming the input and the problem, or in correct output, with nothing left behind.
# In order: a long argument vector for --prompts; hangs (an OBJ that made the UV atlas cubic, named
# pipes wherever a file is read); inputs checked before the run folder is made; nothing cut
# (long paths and prompts, NUL bytes and CR line ends in --prompts); messages that repeat nothing
# of another file; no NaN read in; sd txt2img's steps and output name.
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
expect 0 "paint: one triangle given 400 times" -- timeout 900 $Q paint --mesh "$T/rep.obj" -p "a red bowl" $small -o "$T/rep"
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
pipe_refused "paint --mesh a pipe" "$T/p1" $Q paint --mesh "$T/pipe.obj" -p "a red bowl" -o "$T/p1"
pipe_refused "a .gltf whose buffer is a pipe" "$T/p2" $Q paint --mesh "$T/piped.gltf" -p "a red bowl" -o "$T/p2"
pipe_refused "generate --prompts a pipe" "$T/p3" $Q generate --prompts "$T/pipe.txt" -o "$T/p3"
pipe_refused "a run whose config.json is a pipe: generate --resume" - $Q generate --resume "$T/piperun"
pipe_refused "a run whose config.json is a pipe: export" - $Q export "$T/piperun" -o "$T/p5.glb"
[ -e "$T/p5.glb" ] && bad "export: p5.glb left behind" || ok "export: nothing written"

# ---- 4. every input checked before the run folder is made ----
# a file that is not what the option wants (a password file's look-alike), learning rates and --set
# values the options refuse, an --asset in a folder that is not there: exit 1 or 2 at once, naming
# the input and the problem, no run folder
printf 'root:$y$j9T$SECRETHASHabc$xyz:19000:0:99999:7:::\ndaemon:*:19000:0:99999:7:::\n' > "$T/shadow"
refused_early() {   # NAME CODE TEXT generate-or-paint options...
  local name=$1 code=$2 text=$3; shift 3
  rm -rf "$T/early"
  expect "$code" "$name: refused" -- timeout 120 $Q "$@" -o "$T/early"
  err_has "$name: the problem named" "$text"
  [ -e "$T/early" ] && bad "$name: a run folder was made" || ok "$name: no run folder"
}
G="generate -p a-red-bowl --init-iters 1 --geometry-iters 1 --appearance-iters 1"
refused_early "--env a text file" 1 "$T/shadow: not a Radiance .hdr or OpenEXR file" $G --env "$T/shadow"
refused_early "--set envs=a text file" 1 "environment 1 ($T/shadow)" $G --set "envs=sky,$T/shadow"
refused_early "--init a text file" 1 "--init $T/shadow" $G --init "$T/shadow"
refused_early "--init auto: a text file among the candidates" 1 "--init $T/shadow" $G --init "auto:torus,$T/shadow"
refused_early "--init a pipe" 1 "not a regular file (a named pipe)" $G --init "$T/pipe.obj"
refused_early "--set geometry_lr=1e308" 1 "learning rates" $G --set geometry_lr=1e308
refused_early "--set appearance_lr=1e308" 1 "learning rates" $G --set appearance_lr=1e308
refused_early "--set res=12" 1 "multiple of 8 in 16..2048" $G --set res=12
refused_early "--set latent_size=7" 1 "latent_size must be 0 (64) or a multiple of 8" $G --set latent_size=7
refused_early "--set geometry_iters=20000000" 1 "iteration counts" generate -p a-red-bowl --set geometry_iters=20000000
refused_early "--set init_iters=2000000" 1 "init_iters" generate -p a-red-bowl --set init_iters=2000000
refused_early "--set seed=2^64" 2 "more than 18446744073709551615" $G --set seed=18446744073709551616
refused_early "--seed 2^64" 2 "--seed: expected an integer in 0..18446744073709551615" $G --seed 18446744073709551616
refused_early "paint --asset in a missing folder" 1 "/nonexistent/dir/x.glb: cannot create a temporary file beside it" \
  paint --mesh "$T/rep.obj" -p "a red bowl" --asset /nonexistent/dir/x.glb
expect 1 "export -o in a missing folder: refused before the atlas" -- $Q export "$T/rep" -o /nonexistent/dir/x.glb
err_has "export names the output" "/nonexistent/dir/x.glb"

# ---- 3. nothing cut without a word ----
# a path of 1023 bytes naming a mesh, and that path with more after it: the longer one was once cut
# back to the first and painted it; now any argument over 1023 bytes is refused, naming its option
deep="$T"; while [ ${#deep} -lt 900 ]; do deep="$deep/dddddddddddddddddddddddddddddddddddddddddddddddd"; done
mkdir -p "$deep"
fill=$((1023 - ${#deep} - 5)); name=$(head -c "$fill" /dev/zero | tr '\0' m)
prefix="$deep/$name.obj"
cp "$T/rep.obj" "$prefix"
[ ${#prefix} = 1023 ] && ok "a mesh path of 1023 bytes" || bad "prefix is ${#prefix} bytes"
refused_early "paint --mesh of 1037 bytes" 2 "the value of --mesh is 1037 bytes" paint --mesh "$prefix.NOT_THERE.obj" -p "a red bowl"
refused_early "paint --mesh of 5000 bytes" 2 "the value of --mesh is 5000 bytes: a path, a prompt or a name may have at most 1023" \
  paint --mesh "$(head -c 5000 /dev/zero | tr '\0' p)" -p "a red bowl"
# a prompt of 1024 bytes whose 1023rd byte starts a UTF-8 character: refused whole, not cut into invalid UTF-8
long_prompt="$(head -c 1022 /dev/zero | tr '\0' a)é"
refused_early "a prompt of 1024 bytes" 2 "the value of -p is 1024 bytes" $G -p "$long_prompt"
# --prompts: a NUL byte was the silent end of the file, CR-only line ends one merged prompt
printf 'a gold goblet\n--seed 2 a red mug\0 --seed 3 a hidden line\n' > "$T/nul.txt"
expect 2 "--prompts with a NUL byte" -- $Q generate --prompts "$T/nul.txt" -o "$T/pn"
err_has "the NUL byte's line and column" "nul.txt: line 2: a NUL byte at column 19"
[ -e "$T/pn" ] && bad "--prompts NUL: folder made" || ok "--prompts NUL: no folder"
printf 'a gold goblet\ra gold goblet\r' > "$T/cr.txt"
expect 2 "--prompts with CR line ends: two lines" -- $Q generate --prompts "$T/cr.txt" -o "$T/pc"
err_has "the two CR-ended lines seen apart" "lines 1 and 2 both make the run a-gold-goblet-2d3c54a6"

# ---- 5. messages name the file and the problem, never another file's contents ----
for opt in "generate -p a-red-bowl --init-iters 1 --init" "paint -p a-red-bowl --mesh"; do
  rm -rf "$T/m5"
  expect 1 "${opt##* }: a password file's look-alike refused" -- timeout 120 $Q $opt "$T/shadow" -o "$T/m5"
  err_has "${opt##* }: the file and the line named" "$T/shadow: line 1: not an OBJ statement"
  grep -q "SECRETHASH\|root:" "$T/err" && bad "${opt##* }: the message quotes the file" || ok "${opt##* }: nothing of the file quoted"
done
# a .gltf nested 200000 deep: cJSON stops at 1000 levels, and the message says so
{ head -c 200000 /dev/zero | tr '\0' '['; head -c 200000 /dev/zero | tr '\0' ']'; } > "$T/deep.gltf"
expect 1 "a .gltf nested 200000 deep" -- $Q paint --mesh "$T/deep.gltf" -p "a red bowl" -o "$T/m6"
err_has "nesting named" "deep.gltf: not glTF: neither a .glb nor JSON text (JSON nested more than 1000 levels deep"

# ---- 6. no NaN read in ----
nan_tail() { printf "$2" | dd of="$1" bs=1 seek=$(( $(stat -c %s "$1") - 4 )) conv=notrunc status=none; }   # FILE BYTES
# a paint run stopped after a checkpoint, its checkpoint's last number made NaN: --resume refuses it
# naming the file, and the run is left as it was (once it resumed and wrote 1000 NaNs into
# final/material.safetensors, exit 0)
expect 0 "paint stopped after its first checkpoint" -- $Q paint --mesh "$T/rep.obj" -p "a red bowl" $small \
  --appearance-iters 2 --checkpoint-every 1 --stop-after 1 -o "$T/nanrun"
ck="$T/nanrun/checkpoints/appearance.safetensors"
nan_tail "$ck" '\x00\x00\xc0\x7f'
cp "$T/nanrun/loss.csv" "$T/loss_before.csv"
expect 1 "paint --resume of a checkpoint holding a NaN" -- $Q paint --resume "$T/nanrun"
err_has "the checkpoint and the tensor named" "appearance.safetensors: tensor 'adam_v' holds a NaN or an infinity"
[ -e "$T/nanrun/final/material.safetensors" ] && bad "a material written from the NaN" || ok "no material written"
cmp -s "$T/loss_before.csv" "$T/nanrun/loss.csv" && ok "the run left as it was (loss.csv)" || bad "loss.csv changed"
# a diffusion model whose UNet holds a NaN: refused when it loads (a NaN UNet once gave a guidance
# loss of 0 without a word)
cp -r "$(dirname "$0")/../models/matlaber-tiny-appearance" "$T/nanmodel"
nan_tail "$T/nanmodel/unet/diffusion_pytorch_model.safetensors" '\x00\xfe\xff\x7f'   # NaN as F32, F16 or BF16
expect 1 "sd txt2img with a NaN in the UNet" -- $Q sd txt2img -m "$T/nanmodel" -p "a red bowl" -o "$T/nan.png"
err_has "the weights file named" "diffusion_pytorch_model.safetensors: tensor '.*' holds a NaN or an infinity"
[ -e "$T/nan.png" ] && bad "an image written" || ok "no image written"
refused_early "generate with a NaN in the UNet" 1 "holds a NaN or an infinity" $G -m "$T/nanmodel" --preset tiny

# ---- 7. sd txt2img says what it takes ----
expect 0 "sd txt2img --help" -- $M sd txt2img --help
grep -q -- "--steps N .*1\.\.999" "$T/out" && ok "help gives the steps' range" || bad "help: $(grep -- --steps "$T/out")"
expect 2 "sd txt2img --steps 1000 (a 1000th step would be timestep 1000 of 0..999)" -- $Q sd txt2img -p "a red bowl" --steps 1000 -o "$T/s.png"
err_has "the range named" "--steps: expected 1..999"
expect 2 "sd txt2img -o x.jpg (the bytes are PNG)" -- $Q sd txt2img -p "a red bowl" --steps 1 -o "$T/x.jpg"
err_has "the name refused" "-o $T/x.jpg: the image is written as PNG: give a name ending in .png"
[ -e "$T/x.jpg" ] && bad "x.jpg written" || ok "no x.jpg"
expect 1 "sd txt2img -o in a missing folder: before sampling" -- $Q sd txt2img -p "a red bowl" --steps 1 -o /nonexistent/dir/x.png
err_has "the output named" "/nonexistent/dir/x.png: cannot create a temporary file beside it"
expect 0 "sd txt2img -o X.PNG" -- $Q sd txt2img -p "a red bowl" --steps 1 -o "$T/x.PNG"
[ "$(head -c 4 "$T/x.PNG" | od -An -c | tr -d ' ')" = "211PNG" ] && ok "a PNG" || bad "not a PNG"

finish
