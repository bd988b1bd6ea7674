#!/usr/bin/env bash
# The pipeline's commands end to end: fit (weights-free) on a rendered views folder, resume after a
# stop, relight and interp on finished runs, export, and (with ../shared/data) generate with the
# tiny SD fixture for 2 steps per stage. Usage errors and their exit codes.
set -u
M=${1:?usage: cli_pipeline.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
Q="$M --log-level warn"

for c in generate fit interp "relight" demo; do expect 0 "$c --help" -- $M $c --help; done
expect 2 "generate without -p" -- $M generate -m /x -o "$T/r"
# without -m: the project's own model ($MATLABER_MODEL, else models/matlaber-tiny), here a missing one
expect 1 "generate without -m, no model there" -- env MATLABER_MODEL="$T/no-model" $M generate -p x -o "$T/r"
err_has "the missing model named" "no-model"
expect 2 "fit without --views" -- $M fit -o "$T/r"
expect 2 "fit bad --res" -- $M fit --views "$T/v" -o "$T/r" --res 100
expect 2 "fit bad --material" -- $M fit --views "$T/v" -o "$T/r" --material shiny
# the guidance scales are numbers to the options; their range is the config's check, which names them
expect 2 "generate --guidance-scale not a number" -- $M generate -p x -m /x --guidance-scale lots -o "$T/r"
err_has "not a number: the option named" "--guidance-scale: expected a number"
expect 1 "generate --guidance-scale out of range" -- $M generate -p x -m /x --guidance-scale 20000 -o "$T/r"
err_has "out of range: the option, its key and the range named" \
  "the guidance scale (--guidance-scale, guidance_scale) must be in \[0, 10000\]"
expect 1 "generate --appearance-guidance-scale out of range" -- $M generate -p x -m /x --appearance-guidance-scale -1 -o "$T/r"
err_has "out of range: the appearance stage's option named" "(--appearance-guidance-scale, appearance_guidance_scale)"
expect 1 "fit on a missing folder" -- $M fit --views "$T/nothing" -o "$T/r"
err_has "missing folder named" "nothing"
[ -e "$T/r" ] && bad "no run folder after errors" || ok "no run folder after errors"
expect 1 "resume of a non-run" -- $M fit --resume "$T"
expect 1 "interp of non-runs" -- $M interp "$T/a" "$T/b"

# a small data set of the goblet, and small fits of it
expect 0 "render a views folder" -- $Q render --goblet --views-out "$T/v" --views 8 --res 32 --env sky,studio --seed 2
# the SDF initialisation's steps and the hash tables cut small (defaults 400 steps, 2^19 entries: most
# of each run's time, most of all under the sanitizers); what these runs check is the plumbing
fast="--init-iters 40 --hash-table-log2 14"
small="$fast --res 32 --grid 24 --geometry-iters 6 --appearance-iters 6 --views-per-step 2 --checkpoint-every 2 --preview-every 3"
expect 0 "fit (uninterrupted)" -- $Q fit --views "$T/v" $small -o "$T/a"
for f in config.json loss.csv loss.png final/mesh.obj final/mesh_ks.obj final/mesh_roughness.obj final/material.safetensors \
         final/views.png previews/geometry_000003.png previews/appearance_000006.png; do
  [ -s "$T/a/$f" ] && ok "run has $f" || bad "run lacks $f"
done
expect 1 "fit into an existing run" -- $Q fit --views "$T/v" $small -o "$T/a"
err_has "suggests resume" "resume"
expect 0 "fit stopped after 5 steps" -- $Q fit --views "$T/v" $small -o "$T/b" --stop-after 5
grep -q "resume" "$T/out" && ok "stop says how to resume" || bad "stop message lacks resume"
[ -e "$T/b/final/mesh.obj" ] && bad "stopped run has final/" || ok "stopped run has no final/"
expect 0 "resume" -- $Q fit --resume "$T/b"
for f in final/material.safetensors final/mesh.obj loss.csv; do
  cmp -s "$T/a/$f" "$T/b/$f" && ok "resumed $f identical" || bad "resumed $f differs"
done
expect 2 "generate --resume of a fit run" -- $Q generate --resume "$T/a"

# downstream
expect 0 "relight RUN_DIR" -- $Q relight "$T/a" --env overcast --frames 3 --res 48 -o "$T/rl"
[ "$(png_size "$T/rl/frame_0002.png")" = "48x48" ] && ok "relight frames" || bad "relight frame size"
expect 0 "second run (direct)" -- $Q fit --views "$T/v" $small --material direct -o "$T/c"
expect 1 "interp needs latent runs" -- $Q interp "$T/a" "$T/c"
err_has "interp names the direct run" "direct"
expect 0 "interp A B" -- $Q interp "$T/a" "$T/b" --steps 3 --res 48 -o "$T/ip"
[ -s "$T/ip/interp.png" ] && [ -s "$T/ip/step_02.png" ] && ok "interp images" || bad "interp images missing"
expect 0 "export glb" -- $Q export "$T/a" --format glb --texture-size 128 -o "$T/a.glb"
[ "$(head -c 4 "$T/a.glb")" = "glTF" ] && ok "glb magic" || bad "not a glb"

# generate with the tiny SD fixture (random weights; only the plumbing is checked)
D=${MLB_SHARED_DATA:-$(dirname "$0")/../../shared/data}
R="$D/sd_reference/sd1_diffusers"
if [ -d "$R" ]; then
  expect 0 "generate, 2 steps per stage, tiny SD" -- $Q generate -p "a golden goblet" -m "$R" $fast --res 64 --grid 16 \
    --geometry-iters 2 --appearance-iters 2 --views 2 --preview-every 1 -o "$T/g"
  [ -s "$T/g/final/mesh.obj" ] && ok "generate wrote the asset" || bad "generate: no asset"
  [ -s "$T/g/previews/geometry_000001.png" ] && ok "geometry preview" || bad "no geometry preview"
  grep -q '"prompt":[[:space:]]*"a golden goblet"' "$T/g/config.json" && ok "config records the prompt" || bad "config lacks the prompt"
  grep -q '"view_prompts":[[:space:]]*1' "$T/g/config.json" && ok "view prompts on by default" || bad "config: view_prompts not 1"
  expect 0 "generate --no-view-prompts, stopped after its first step" -- $Q generate -p "a golden goblet" -m "$R" $fast \
    --res 64 --grid 16 --geometry-iters 1 --appearance-iters 1 --views 2 --no-view-prompts --stop-after 1 -o "$T/g2"
  grep -q '"view_prompts":[[:space:]]*0' "$T/g2/config.json" && ok "--no-view-prompts recorded" || bad "config: view_prompts not 0"
  # the cpu preset, shortened: both stages (the geometry's latent and VAE phases), stopped after a
  # checkpoint and resumed, ending in final/asset.glb; options after --preset override it
  expect 2 "unknown preset" -- $M generate --preset fast -p x -m "$R" -o "$T/p0"
  err_has "unknown preset lists the presets" "paper, cpu"
  expect 0 "generate --preset cpu, stopped after 3 steps" -- $Q generate --preset cpu -p "a golden goblet" -m "$R" \
    $fast --geometry-iters 3 --appearance-iters 2 --checkpoint-every 2 --export-texture 512 --stop-after 3 -o "$T/p"
  for kv in '"views":[[:space:]]*1,' '"res":[[:space:]]*256,' '"grid":[[:space:]]*64,' '"precision":[[:space:]]*"bf16"' \
            '"latent_iters":[[:space:]]*1,' '"checkpoint_every":[[:space:]]*2,' '"export_texture":[[:space:]]*512,'; do
    grep -q "$kv" "$T/p/config.json" && ok "preset run: $kv" || bad "preset run config lacks $kv"
  done
  [ -e "$T/p/final/asset.glb" ] && bad "stopped preset run has a .glb" || ok "stopped preset run has no .glb"
  expect 2 "--preset with --resume" -- $Q generate --resume "$T/p" --preset cpu
  expect 0 "resume the preset run" -- $Q generate --resume "$T/p"
  [ "$(head -c 4 "$T/p/final/asset.glb" 2> /dev/null)" = "glTF" ] && ok "preset run ends in final/asset.glb" || bad "no final/asset.glb"
  for stage in 0 1; do   # loss.csv's stage column: 0 geometry, 1 appearance
    grep -q "^$stage," "$T/p/loss.csv" && ok "preset run: stage $stage steps in loss.csv" || bad "preset run: no stage $stage steps"
  done
  # a single-file checkpoint carries no tokenizer: the error names both ways of giving one, either
  # works, and the run's config keeps --tokenizer so that its resume finds it again
  F="$D/sd_reference/sd1_tiny.safetensors"
  expect 1 "generate from a single file without a tokenizer" -- env -u MATLABER_TOKENIZER $Q generate -p x -m "$F" \
    --res 64 --grid 16 --geometry-iters 1 --appearance-iters 1 --views 1 -o "$T/s0"
  err_has "names --tokenizer" "--tokenizer PATH or \$MATLABER_TOKENIZER"
  expect 0 "generate from a single file, --tokenizer, stopped after a step" -- env -u MATLABER_TOKENIZER $Q generate \
    -p "a golden goblet" -m "$F" --tokenizer "$R/tokenizer" $fast --res 64 --grid 16 --geometry-iters 1 --appearance-iters 1 \
    --views 1 --checkpoint-every 1 --stop-after 1 -o "$T/s1"
  grep -q '"tokenizer":[[:space:]]*"[^"]*tokenizer"' "$T/s1/config.json" && ok "config keeps --tokenizer" || bad "config lacks the tokenizer"
  expect 0 "resume the single-file run" -- env -u MATLABER_TOKENIZER $Q generate --resume "$T/s1"
  [ -s "$T/s1/final/mesh.obj" ] && ok "single-file run finished" || bad "single-file run: no asset"
  # a model per stage: a missing one is named before any folder is made; the pair is recorded in
  # config.json and the run resumes with both
  expect 1 "generate with a missing --appearance-model" -- $Q generate -p x -m "$R" --appearance-model "$T/no-app" \
    --res 64 --grid 16 --geometry-iters 1 --appearance-iters 1 --views 1 -o "$T/am0"
  err_has "the missing appearance model named" "no-app"
  [ -e "$T/am0" ] && bad "no run folder after a missing appearance model" || ok "no run folder after a missing appearance model"
  expect 0 "generate with --appearance-model, stopped after a step" -- env -u MATLABER_TOKENIZER $Q generate \
    -p "a golden goblet" -m "$R" --appearance-model "$F" --tokenizer "$R/tokenizer" $fast --res 64 --grid 16 \
    --geometry-iters 1 --appearance-iters 1 --views 1 --checkpoint-every 1 --stop-after 1 -o "$T/am"
  grep -q '"appearance_model":[[:space:]]*"[^"]*sd1_tiny.safetensors"' "$T/am/config.json" && ok "config keeps the appearance model" \
    || bad "config lacks the appearance model"
  expect 0 "resume the run with an appearance model" -- env -u MATLABER_TOKENIZER $Q generate --resume "$T/am"
  [ -s "$T/am/final/mesh.obj" ] && ok "the run with an appearance model finished" || bad "appearance-model run: no asset"
  expect 0 "generate from a single file, \$MATLABER_TOKENIZER" -- env MATLABER_TOKENIZER="$R/tokenizer" $Q generate \
    -p "a golden goblet" -m "$F" $fast --res 64 --grid 16 --geometry-iters 1 --appearance-iters 1 --views 1 -o "$T/s2"
else
  echo "skip: no shared sd_reference fixture for generate"
fi
finish
