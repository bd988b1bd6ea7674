#!/usr/bin/env bash
# 'matlaber render', 'relight' and 'brdf swatch' end to end on small images: outputs, sizes,
# exit codes, and errors that name the bad file.
set -u
M=${1:?usage: cli_render.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"

# a tetrahedron, CCW from outside
cat > "$T/tet.obj" <<'OBJ'
v 1 1 1
v -1 -1 1
v -1 1 -1
v 1 -1 -1
f 1 2 4
f 1 4 3
f 1 3 2
f 2 3 4
OBJ
FAST="--size 32 --cube 64 --supersample 1"
for c in render relight; do expect 0 "$c --help" -- $M $c --help; done
expect 0 "brdf swatch --help" -- $M brdf swatch --help
expect 0 "render a tetrahedron" -- $M render --mesh "$T/tet.obj" $FAST --env overcast -o "$T/a.png"
[ "$(png_size "$T/a.png")" = "32x32" ] && ok "render writes a 32x32 PNG" || bad "render size $(png_size "$T/a.png")"
expect 0 "render to EXR" -- $M render --mesh "$T/tet.obj" $FAST --env studio --latent 0,0,0,0 -o "$T/a.exr"
[ -s "$T/a.exr" ] && ok "EXR written" || bad "EXR missing"
expect 0 "relight 3 frames" -- $M relight --mesh "$T/tet.obj" $FAST --env sky --frames 3 -o "$T/frames"
[ -f "$T/frames/frame_0000.png" ] && [ -f "$T/frames/frame_0002.png" ] && [ ! -f "$T/frames/frame_0003.png" ] \
  && ok "relight frames" || bad "relight frames: $(ls "$T/frames")"
cmp -s "$T/frames/frame_0000.png" "$T/frames/frame_0001.png" && bad "the light did not move" || ok "frames differ as the light turns"
expect 0 "swatch of two materials" -- $M brdf swatch --k 0.8,0.1,0.1,0.04,0.04,0.04,0.3 --k 0,0,0,1,0.766,0.336,0.3 --size 24 -o "$T/s.png"
[ "$(png_size "$T/s.png")" = "48x24" ] && ok "swatch is one row of spheres" || bad "swatch size $(png_size "$T/s.png")"
expect 0 "swatch of a latent interpolation" -- $M brdf swatch --from-z -1,0,0,0 --to-z 1,0,0,0 --steps 3 --size 16 -o "$T/i.png"
[ "$(wc -l < "$T/out")" = 3 ] && ok "swatch prints the 3 decoded BRDFs" || bad "swatch rows"

# multi-view data sets (docs/views.md)
VFAST="--res 32 --cube 64 --supersample 1 --views 3"
expect 0 "render the goblet into a views folder" -- $M render --goblet --views-out "$T/views" $VFAST --env sky,studio --seed 5
[ -f "$T/views/cameras.json" ] && grep -q '"format":[[:space:]]*"matlaber-views"' "$T/views/cameras.json" \
  && ok "cameras.json written" || bad "cameras.json missing or wrong"
[ -f "$T/views/view_002.png" ] && [ -f "$T/views/normal_002.png" ] && [ ! -e "$T/views/view_003.png" ] \
  && ok "3 views and their normal maps" || bad "views folder: $(ls "$T/views")"
[ "$(png_size "$T/views/view_001.png")" = "32x32" ] && [ "$(png_size "$T/views/normal_001.png")" = "32x32" ] \
  && ok "views are 32x32" || bad "view size $(png_size "$T/views/view_001.png")"
[ "$(grep -c '"image"' "$T/views/cameras.json")" = 3 ] && ok "3 entries in cameras.json" || bad "cameras.json entries"
expect 0 "the same seed again" -- $M render --goblet --views-out "$T/views2" $VFAST --env sky,studio --seed 5
cmp -s "$T/views/cameras.json" "$T/views2/cameras.json" && cmp -s "$T/views/view_001.png" "$T/views2/view_001.png" \
  && ok "same seed, same data set" || bad "the same seed gave another data set"
expect 0 "another seed" -- $M render --goblet --views-out "$T/views3" $VFAST --env sky,studio --seed 6
cmp -s "$T/views/cameras.json" "$T/views3/cameras.json" && bad "another seed gave the same cameras" || ok "another seed, other cameras"
expect 0 "a mesh with a material into a views folder" -- $M render --mesh "$T/tet.obj" --kd 0.8,0.2,0.1 --views-out "$T/tv" $VFAST --env white
[ -f "$T/tv/view_000.png" ] && ok "tetrahedron views" || bad "tetrahedron views missing"
expect 2 "--views-out and -o together" -- $M render --goblet --views-out "$T/x" -o "$T/x.png"
expect 2 "--goblet has its own materials" -- $M render --goblet --kd 1,0,0 -o "$T/x.png"
expect 2 "--views 0" -- $M render --goblet --views-out "$T/x" --views 0
expect 2 "bad --elevation" -- $M render --goblet --views-out "$T/x" --elevation 50,10
expect 2 "--views-out is not for relight" -- $M relight --goblet --views-out "$T/x"
expect 1 "missing environment file in the list" -- $M render --goblet --views-out "$T/x" $VFAST --env sky,"$T/none.hdr"
err_has "missing environment names the file" "none.hdr"

# errors
expect 2 "render needs --mesh" -- $M render -o "$T/x.png"
expect 2 "bad --view" -- $M render --mesh "$T/tet.obj" --view 10 -o "$T/x.png"
expect 2 "invalid material" -- $M render --mesh "$T/tet.obj" --kr 3 -o "$T/x.png"
expect 1 "missing mesh" -- $M render --mesh "$T/none.obj" $FAST -o "$T/x.png"
err_has "missing mesh names the file" "none.obj"
printf 'v 0 0 0\nv 1 0 0\nf 1 2 7\n' > "$T/badidx.obj"
expect 1 "OBJ index out of range" -- $M render --mesh "$T/badidx.obj" $FAST -o "$T/x.png"
err_has "bad index names the file and line" "badidx.obj: line 3"
printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X 16\n' > "$T/trunc.hdr"
expect 1 "truncated HDR" -- $M render --mesh "$T/tet.obj" $FAST --env "$T/trunc.hdr" -o "$T/x.png"
err_has "truncated HDR names the file" "trunc.hdr"
[ ! -e "$T/x.png" ] && ok "failures write no image" || bad "a failed render left x.png"

echo "$pass passed, $fail failed"
[ "$fail" = 0 ]
