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
