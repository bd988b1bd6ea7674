#!/usr/bin/env bash
# The static viewer end to end: test_export writes a viewer folder for a textured sphere
# (mlb_viewer_write_asset), then tests/viewer_check.mjs serves it on 127.0.0.1 and opens it in
# headless Chromium (playwright-core): no console errors, the asset is drawn, the light slider
# and the map toggles change the picture, nothing is fetched from outside the folder; then a
# latent-mode run's folder, whose editor must reproduce the baked maps at zero offset and move.
# Skipped (77) without node, Chromium, or viewer/node_modules (scripts/build.sh runs npm ci).
set -u
M=${1:?usage: cli_viewer.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
HERE=$(cd "$(dirname "$0")" && pwd)
W="$(dirname "$M")/tests/test_export"
[ -x "$W" ] || { echo "skip: $W not built"; exit 77; }
command -v node > /dev/null || { echo "skip: node not installed (scripts/install-deps.sh)"; exit 77; }
for p in three playwright-core; do
  [ -f "$HERE/../viewer/node_modules/$p/package.json" ] \
    || { echo "skip: viewer/node_modules/$p missing (scripts/build.sh runs npm ci)"; exit 77; }
done
[ -x /usr/bin/chromium ] || [ -n "${CHROMIUM:-}" ] || { echo "skip: no /usr/bin/chromium (scripts/install-deps.sh)"; exit 77; }

expect 0 "write the viewer folder" -- "$W" --write-viewer "$T/view"
for f in index.html viewer.js viewer.json asset.glb env/sky.hdr env/studio.hdr env/overcast.hdr \
         lib/three/build/three.module.js lib/three/examples/jsm/loaders/GLTFLoader.js; do
  [ -s "$T/view/$f" ] && ok "$f" || bad "$f missing"
done
grep -Eq '(src|href)="(https?:)?//' "$T/view/index.html" "$T/view/viewer.js" && bad "the page links to the network" \
  || ok "the page links nothing on the network"
node "$HERE/viewer_check.mjs" "$T/view" "${MLB_VIEWER_SHOTS:-}" > "$T/out" 2>&1
rc=$?
cat "$T/out"
[ "$rc" = 77 ] && { echo "skip: $(tail -1 "$T/out")"; exit 77; }
[ "$rc" = 0 ] && ok "headless Chromium checks" || bad "headless Chromium checks (exit $rc)"
grep -q '"decoder"' "$T/view/viewer.json" && bad "a direct asset's viewer names a decoder" || ok "no latent editor for a direct asset"

# a latent-mode run's viewer: its codes and decoder beside asset.glb, the editor in the page
expect 0 "write a latent-mode run's viewer folder" -- "$W" --write-latent-viewer "$T/latent"
for f in asset.glb asset.decoder.json asset.latent.bin latent.js; do
  [ -s "$T/latent/$f" ] && ok "latent: $f" || bad "latent: $f missing"
done
grep -q '"decoder":[[:space:]]*"asset.decoder.json"' "$T/latent/viewer.json" && ok "viewer.json names the decoder" \
  || bad "viewer.json: $(cat "$T/latent/viewer.json")"
MLB_EXPECT_LATENT=1 node "$HERE/viewer_check.mjs" "$T/latent" "${MLB_VIEWER_SHOTS:+$MLB_VIEWER_SHOTS/latent}" > "$T/out" 2>&1
rc=$?
cat "$T/out"
[ "$rc" = 0 ] && ok "headless Chromium checks of the latent editor" || bad "latent editor checks (exit $rc)"
finish
