#!/usr/bin/env bash
# The .glb writer checked by the Khronos glTF-Validator (npm gltf-validator, installed in viewer/
# by scripts/build.sh): the test asset (a textured sphere written by test_export) must have no
# errors, and a truncated copy must be caught. Skipped (77) without node or the package.
set -u
M=${1:?usage: cli_export.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
HERE=$(cd "$(dirname "$0")" && pwd)
W="$(dirname "$M")/tests/test_export"
[ -x "$W" ] || { echo "skip: $W not built"; exit 77; }
command -v node > /dev/null || { echo "skip: node not installed (scripts/install-deps.sh)"; exit 77; }
[ -f "$HERE/../viewer/node_modules/gltf-validator/package.json" ] \
  || { echo "skip: viewer/node_modules/gltf-validator missing (scripts/build.sh runs npm ci)"; exit 77; }

expect 0 "write the test asset as .glb" -- "$W" --write-glb "$T/sphere.glb"
expect 0 "glTF-Validator: no errors" -- node "$HERE/gltf_validate.mjs" "$T/sphere.glb"
cat "$T/out"
grep -q "0 errors, 0 warnings" "$T/out" && ok "no warnings either" || bad "validator warnings: $(head -1 "$T/out")"
grep -q "KHR_materials_specular" "$T/out" && ok "the validator sees KHR_materials_specular" || bad "extension not reported"
grep -q "images/2 image/png 64x64" "$T/out" && ok "three embedded PNGs" || bad "embedded images: $(cat "$T/out")"
head -c 2000 "$T/sphere.glb" > "$T/cut.glb"
expect 1 "a truncated .glb fails validation" -- node "$HERE/gltf_validate.mjs" "$T/cut.glb"
expect 0 "write the test asset as OBJ" -- "$W" --write-obj "$T/sphere.obj"
for f in sphere.obj sphere.mtl sphere_kd.png sphere_ks.png sphere_roughness.png; do
  [ -s "$T/$f" ] && ok "$f written" || bad "$f missing"
done
[ "$(png_size "$T/sphere_kd.png")" = "64x64" ] && ok "kd texture 64x64" || bad "kd size $(png_size "$T/sphere_kd.png")"
[ -z "$(ls "$T" | grep '\.tmp\.')" ] && ok "no temporary files left" || bad "temporaries: $(ls "$T")"

# 'matlaber export' and 'matlaber view' on a run folder (tools/matlaber/cmd_export.c), once wired
if "$M" export --help > /dev/null 2>&1; then
  expect 0 "export --help" -- "$M" export --help
  expect 0 "view --help" -- "$M" view --help
  expect 0 "a run folder (final/mesh.obj, final/material.safetensors)" -- "$W" --write-run "$T/run"
  expect 0 "export a run as .glb" -- "$M" export "$T/run" --texture-size 64 -o "$T/run.glb"
  expect 0 "the run's .glb passes the glTF-Validator" -- node "$HERE/gltf_validate.mjs" "$T/run.glb"
  expect 0 "export a run as OBJ" -- "$M" export "$T/run" --format obj --texture-size 64 -o "$T/run.obj"
  [ "$(png_size "$T/run_kd.png")" = "64x64" ] && ok "--texture-size sets the baked size" || bad "run_kd.png $(png_size "$T/run_kd.png")"
  expect 0 "view a .glb" -- "$M" view "$T/run.glb" --env studio -o "$T/view"
  [ -s "$T/view/index.html" ] && [ -s "$T/view/env/studio.hdr" ] && [ ! -e "$T/view/env/sky.hdr" ] \
    && ok "the viewer folder with the chosen environment" || bad "viewer folder: $(ls -R "$T/view" | head)"
  [ ! -e "$T/run.decoder.json" ] && [ ! -e "$T/run.latent.bin" ] && ok "a direct-mode run: no latent files" || bad "direct run wrote latent files"
  grep -q '"decoder"' "$T/view/viewer.json" && bad "a direct asset's viewer names a decoder" || ok "its viewer names no decoder"
  # a latent-mode run: its codes and decoder beside the .glb, carried into the viewer (docs/export.md)
  expect 0 "a latent-mode run folder" -- "$W" --write-latent-run "$T/lrun"
  expect 0 "export it as .glb" -- "$M" export "$T/lrun" --texture-size 32 -o "$T/lrun.glb"
  [ "$(wc -c < "$T/lrun.latent.bin")" = $((32 * 32 * 16)) ] && ok "lrun.latent.bin: 32² codes of 4 float32" || bad "lrun.latent.bin missing or sized otherwise"
  grep -q '"file":"lrun.latent.bin"' "$T/lrun.decoder.json" && ok "lrun.decoder.json names it" || bad "lrun.decoder.json"
  expect 0 "view the .glb" -- "$M" view "$T/lrun.glb" --env studio -o "$T/lview"
  cmp -s "$T/lrun.latent.bin" "$T/lview/asset.latent.bin" && cmp -s "$T/lrun.decoder.json" "$T/lview/asset.decoder.json" \
    && ok "view copies the codes and decoder beside asset.glb" || bad "view: $(ls "$T/lview")"
  grep -q '"decoder":[[:space:]]*"asset.decoder.json"' "$T/lview/viewer.json" && ok "and names the decoder" || bad "lview/viewer.json"
  expect 0 "view the run folder" -- "$M" view "$T/lrun" --texture-size 32 --env studio -o "$T/lview2"
  cmp -s "$T/lrun.latent.bin" "$T/lview2/asset.latent.bin" && ok "view RUN_DIR writes the same codes" || bad "lview2: $(ls "$T/lview2")"
  expect 2 "export needs -o" -- "$M" export "$T/run"
  expect 2 "export: unknown format" -- "$M" export "$T/run" --format fbx -o "$T/x.fbx"
  expect 2 "export: an OBJ name must end in .obj" -- "$M" export "$T/run" --format obj -o "$T/x.glb"
  expect 1 "export: a missing run" -- "$M" export "$T/none" -o "$T/x.glb"
  err_has "the message names the run folder" "none"
  mkdir -p "$T/empty"
  expect 1 "export: a run without final/mesh.obj" -- "$M" export "$T/empty" -o "$T/x.glb"
  err_has "the message names the missing mesh" "final/mesh.obj"
  expect 2 "view: unknown environment" -- "$M" view "$T/run.glb" --env moon -o "$T/v2"
  [ ! -e "$T/x.glb" ] && ok "failures write nothing" || bad "a failed export left x.glb"
else
  echo "note: 'matlaber export' is not a command of this build yet: its checks are left out"
fi
finish
