#!/usr/bin/env bash
# What the project's own models read (docs/catalogue.md, "What the built-in model reads"): generate,
# paint and sd txt2img refuse a prompt with words the model never saw (exit 2, the words named, the
# classes and materials listed, -m said; no run folder, no output file), read the ways people write
# a caption into the catalogue's (the same bits as the caption itself), and with a model that is not
# the project's (the same weights without model_index.json's "_matlaber") take the prompt as typed.
set -u
M=${1:?usage: cli_words.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
OWN=$(cd "$(dirname "$0")/../models" && pwd)
if [ ! -f "$OWN/matlaber-tiny/model_index.json" ] || [ ! -f "$OWN/matlaber-tiny-appearance/model_index.json" ]; then
  echo "skip: the project's own models are not in models/"; exit 77; fi
unset MATLABER_MODEL MATLABER_APPEARANCE_MODEL
Q="$M --log-level warn"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n' > "$T/tet.obj"

refused() {   # NAME TEXT...: the last command's message says it all
  err_has "$1: the words named" "$2"
  err_has "$1: the classes listed" "goblet, vase, bowl, mug, bottle, mushroom, table, stool, lamp, ring, teapot"
  err_has "$1: the materials listed" "gold, silver, copper, red, blue, white, stone, green"
  err_has "$1: -m said" "any prompt works with Stable Diffusion weights (-m MODEL)"
}
expect 2 "generate: a word the model never saw" -- $Q generate -p "a wooden chair" -o "$T/g0"
refused "generate" "never saw the words 'wooden', 'chair'"
[ -e "$T/g0" ] && bad "generate: a run folder after the refusal" || ok "generate: no run folder"
expect 2 "paint: a word the model never saw" -- $Q paint --mesh "$T/tet.obj" -p "a shiny gold goblet" --asset "$T/p0.glb" -o "$T/p0"
refused "paint" "never saw the word 'shiny'"
[ -e "$T/p0" ] || [ -e "$T/p0.glb" ] && bad "paint: output after the refusal" || ok "paint: no run folder, no asset"
expect 2 "sd txt2img: a word the model never saw" -- $Q sd txt2img -p "A Wooden Goblet" --steps 1 -o "$T/t0.png"
refused "sd txt2img" "never saw the word 'Wooden'"
[ -e "$T/t0.png" ] && bad "sd txt2img: an image after the refusal" || ok "sd txt2img: no image"
expect 2 "generate: no object named" -- $Q generate -p "gold" -o "$T/g1"
err_has "no object: said" "names none of its objects"
expect 2 "generate: a view in the prompt" -- $Q generate -p "a gold goblet, side view" -o "$T/g1"
err_has "the view named" "names a view ('side view')"
expect 2 "generate: a normal map in the prompt" -- $Q generate -p "a gold goblet, normal map" -o "$T/g1"
err_has "the normal map named" "asks for a normal map"
[ -e "$T/g1" ] && bad "a run folder after the refusals" || ok "no run folder after the refusals"
# the geometry captions: sd txt2img samples them from a model trained with them, and says which is not
expect 0 "txt2img 'A gold goblet normal map'" -- $M sd txt2img -p "A gold goblet normal map" --steps 1 -o "$T/n.png"
err_has "the geometry caption read" "read as 'a gold goblet, normal map'"
expect 2 "txt2img: a normal map from a model without the captions" -- $Q sd txt2img -m "$OWN/matlaber-tiny" \
  -p "a gold goblet, normal map" --steps 1 -o "$T/n2.png"
err_has "says the model lacks them" "not trained with normal-map captions"
[ -e "$T/n2.png" ] && bad "an image after the refusal" || ok "no image after the refusal"
printf -- '--name w a wooden chair\n' > "$T/prompts.txt"
expect 1 "generate --prompts: the line refused" -- $Q generate --prompts "$T/prompts.txt" -o "$T/pp"
grep -q '"status":[[:space:]]*"failed"' "$T/pp/summary.json" && ok "--prompts: the line failed" || bad "--prompts: not failed"
[ -e "$T/pp/w" ] && bad "--prompts: a run folder for the refused line" || ok "--prompts: no run folder for it"

# the ways of writing a caption give the caption's own bits
expect 0 "txt2img 'A golden goblet.'" -- $M sd txt2img -p "A golden goblet." --steps 2 -o "$T/a.png"
err_has "the reading logged" "read as 'a gold goblet'"
expect 0 "txt2img 'a gold goblet'" -- $Q sd txt2img -p "a gold goblet" --steps 2 -o "$T/b.png"
expect 0 "txt2img 'a red goblet'" -- $Q sd txt2img -p "a red goblet" --steps 2 -o "$T/c.png"
cmp -s "$T/a.png" "$T/b.png" && ok "txt2img: the same image, bit for bit" || bad "txt2img: the phrasing changed the image"
cmp -s "$T/a.png" "$T/c.png" && bad "txt2img: another material gave the same image" || ok "txt2img: the prompt still matters"
small="--init ellipsoid --init-iters 10 --geometry-iters 1 --appearance-iters 1 --views 1 --res 32 --grid 16 --hash-table-log2 12 --export-texture 0 --preview-every 0 --set material_start=0"
expect 0 "generate 'A Golden Goblet.'" -- $Q generate -p "A Golden Goblet." $small -o "$T/r1"
expect 0 "generate 'a gold goblet'" -- $Q generate -p "a gold goblet" $small -o "$T/r2"
for f in final/mesh.obj final/material.safetensors loss.csv; do
  cmp -s "$T/r1/$f" "$T/r2/$f" && ok "generate: $f the same" || bad "generate: $f differs"
done
grep -q '"prompt":[[:space:]]*"A Golden Goblet."' "$T/r1/config.json" && ok "config: the prompt as typed" || bad "config: prompt"
grep -q '"caption":[[:space:]]*"a gold goblet"' "$T/r1/config.json" && ok "config: what it was read as" || bad "config: no caption"

# a model that is not the project's: the same weights without the marker take the prompt as typed
mkdir -p "$T/user" && cp -r "$OWN/matlaber-tiny-appearance/." "$T/user/"
grep -v '"_matlaber"' "$OWN/matlaber-tiny-appearance/model_index.json" > "$T/user/model_index.json"
expect 0 "-m a user's model: 'a wooden chair' goes through" -- $Q sd txt2img -m "$T/user" -p "a wooden chair" --steps 1 --size 128 -o "$T/u0.png"
[ -s "$T/u0.png" ] && ok "-m: the image written" || bad "-m: no image"
expect 0 "-m a user's model: 'A golden goblet.'" -- $Q sd txt2img -m "$T/user" -p "A golden goblet." --steps 2 --size 128 --cfg 3 -o "$T/u1.png"
cmp -s "$T/u1.png" "$T/a.png" && bad "-m: the prompt was read, not taken as typed" || ok "-m: the prompt taken as typed"
expect 0 "-m the same folder with the marker: read" -- $Q sd txt2img -m "$OWN/matlaber-tiny-appearance" -p "A golden goblet." --steps 2 --size 128 --cfg 3 -o "$T/u2.png"
cmp -s "$T/u2.png" "$T/a.png" && ok "-m the project's own model: read as without -m" || bad "-m the project's model: another image"
expect 0 "generate -m a user's model: 'a wooden chair'" -- $Q generate -m "$T/user" -p "a wooden chair" --preset tiny $small -o "$T/r3"
grep -q '"prompt":[[:space:]]*"a wooden chair"' "$T/r3/config.json" && ok "generate -m: the prompt as typed" || bad "generate -m: prompt"
grep -q '"caption"' "$T/r3/config.json" && bad "generate -m: a caption recorded" || ok "generate -m: no caption"
finish
