#!/usr/bin/env bash
# 'matlaber geometry init' and 'extract' end to end on a small network: outputs, OBJ contents,
# exit codes, and errors that name the bad file.
set -u
M=${1:?usage: cli_geometry.sh path/to/matlaber}
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
SMALL="--iters 150 --batch 3072 --levels 8 --table-log2 14"
expect 0 "geometry --help" -- $M geometry --help
expect 0 "geometry init --help" -- $M geometry init --help
expect 0 "geometry extract --help" -- $M geometry extract --help
expect 0 "init an ellipsoid" -- $M geometry init --shape ellipsoid --shape-scale 0.8 $SMALL -o "$T/e.safetensors"
grep -q "chamfer to the shape" "$T/out" && ok "init reports the chamfer distance" || bad "no chamfer line: $(cat "$T/out")"
[ -s "$T/e.safetensors" ] && ok "safetensors written" || bad "safetensors missing"
expect 0 "extract" -- $M geometry extract -i "$T/e.safetensors" -o "$T/e.obj"
nv=$(grep -c '^v ' "$T/e.obj"); nn=$(grep -c '^vn ' "$T/e.obj"); nf=$(grep -c '^f ' "$T/e.obj")
[ "$nv" -gt 500 ] && [ "$nv" = "$nn" ] && [ "$nf" -gt 1000 ] && ok "OBJ has v, vn, f ($nv, $nn, $nf)" || bad "OBJ counts $nv $nn $nf"
# the extracted sphere of radius 0.8: every vertex within 0.05 of it
awk '/^v /{r=sqrt($2*$2+$3*$3+$4*$4); if (r<0.75||r>0.85) b++} END{exit b>0}' "$T/e.obj" && ok "vertices near radius 0.8" || bad "vertices off the sphere"
expect 0 "the extracted OBJ loads back" -- $M render --mesh "$T/e.obj" --size 16 --cube 64 --supersample 1 -o "$T/e.png"
expect 0 "init from a mesh" -- $M geometry init --shape "$T/tet.obj" $SMALL -o "$T/t.safetensors"
expect 0 "init a cylinder on the 128 grid" -- $M geometry init --shape cylinder --grid 128 --iters 20 --batch 3072 --levels 4 --table-log2 12 -o "$T/c.safetensors"
expect 0 "extract uses the file's grid" -- $M geometry extract -i "$T/c.safetensors" -o "$T/c.obj"
grep -q "grid 128" "$T/out" && ok "grid 128 from the metadata" || bad "grid: $(cat "$T/out")"
expect 0 "init a cylinder on the 32 grid (the tiny preset's)" -- $M geometry init --shape cylinder --grid 32 --iters 20 --batch 3072 --levels 4 --table-log2 12 -o "$T/c32.safetensors"
expect 0 "extract uses the file's 32 grid" -- $M geometry extract -i "$T/c32.safetensors" -o "$T/c32.obj"
grep -q "grid 32" "$T/out" && ok "grid 32 from the metadata" || bad "grid: $(cat "$T/out")"
# a torus: genus 1, so V - E + F = 0 on the extracted surface (the hole is there)
expect 0 "init a torus" -- $M geometry init --shape torus --iters 150 --batch 3072 --levels 4 --table-log2 12 -o "$T/o.safetensors"
expect 0 "extract the torus" -- $M geometry extract -i "$T/o.safetensors" -o "$T/o.obj"
chi=$(awk '/^v /{v++} /^f /{f++; for (i = 2; i <= 4; i++) { split($i, a, "/"); x[i] = a[1] }
        for (i = 2; i <= 4; i++) { j = i == 4 ? 2 : i + 1; p = x[i] < x[j] ? x[i] "," x[j] : x[j] "," x[i]; if (!(p in e)) { e[p] = 1; n++ } } }
        END{print v - n + f}' "$T/o.obj")
[ "$chi" = 0 ] && ok "the torus keeps its hole (Euler characteristic 0)" || bad "torus Euler characteristic $chi"
# the slab: a flat plate placed high (1.28 x 0.11 x 0.78 at y 0.18..0.28): the extracted surface's box within a cell of it
expect 0 "init a slab" -- $M geometry init --shape slab --iters 150 --batch 3072 --levels 4 --table-log2 12 -o "$T/s.safetensors"
expect 0 "extract the slab" -- $M geometry extract -i "$T/s.safetensors" -o "$T/s.obj"
awk '/^v /{for (k = 2; k <= 4; k++) { if (!(k in lo) || $k < lo[k]) lo[k] = $k; if (!(k in hi) || $k > hi[k]) hi[k] = $k } }
     END{d = 2.1 / 32; exit !(hi[2] - lo[2] > 1.28 - 2 * d && hi[2] - lo[2] < 1.28 + 2 * d && hi[3] - lo[3] < 0.11 + 2 * d &&
                             lo[3] > 0.18 - d && hi[3] < 0.28 + d && hi[4] - lo[4] > 0.78 - 2 * d && hi[4] - lo[4] < 0.78 + 2 * d)}' "$T/s.obj" \
  && ok "the slab's surface is a 1.28 x 0.11 x 0.78 plate at y 0.18..0.28" || bad "slab extent off: $(head -c 300 "$T/s.obj")"

# errors
expect 2 "init needs -o" -- $M geometry init --shape ellipsoid
expect 2 "bad --grid" -- $M geometry init --grid 96 -o "$T/x.safetensors"
expect 2 "unknown subcommand" -- $M geometry fit
expect 2 "extract needs -i" -- $M geometry extract -o "$T/x.obj"
expect 1 "missing shape mesh" -- $M geometry init --shape "$T/none.obj" -o "$T/x.safetensors"
err_has "missing mesh names the file" "none.obj"
expect 1 "extract of a non-network" -- $M geometry extract -i "$T/tet.obj" -o "$T/x.obj"
err_has "bad input names the file" "tet.obj"
[ ! -e "$T/x.safetensors" ] && [ ! -e "$T/x.obj" ] && ok "failures write nothing" || bad "a failure left an output"

echo "$pass passed, $fail failed"
[ "$fail" = 0 ]
