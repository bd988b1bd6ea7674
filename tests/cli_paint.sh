#!/usr/bin/env bash
# matlaber paint (docs/paint.md): hostile meshes refused with the file and the problem, exit 1 and no
# run folder (corrupt .glb / .gltf too); a UV'd cube far from the origin painted at tiny settings with
# the project's own model: the asset keeps its vertices, faces, UVs and positions (scale and placement
# restored), and that .glb painted again reads back as the cube's corners; a stopped
# run resumed ends bitwise where an uninterrupted one does; --progress json's lines.
set -u
M=${1:?usage: cli_paint.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
Q="$M --log-level warn"
HERE=$(cd "$(dirname "$0")" && pwd)

expect 0 "paint --help" -- $M paint --help
grep -q -- "--mesh" "$T/out" && ok "help names --mesh" || bad "help lacks --mesh"
expect 2 "paint without --mesh" -- $M paint -p x -o "$T/r"
expect 2 "paint with a geometry option" -- $M paint --mesh x.obj -p x --grid 32 -o "$T/r"
err_has "the geometry option named" "grid"
expect 2 "paint --uv bad" -- $M paint --mesh x.obj -p x --uv wrap -o "$T/r"
expect 2 "paint --asset bad extension" -- $M paint --mesh x.obj -p x --asset a.fbx -o "$T/r"
expect 2 "generate --mesh" -- $M generate --mesh x.obj -p x -o "$T/r"

# ---- hostile meshes: exit 1, the file and the problem named, nothing written ----
H="$T/hostile"; mkdir -p "$H"
: > "$H/empty.obj"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\n' > "$H/nofaces.obj"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n' > "$H/badindex.obj"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/7 3/1\n' > "$H/baduvindex.obj"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\nf 1 2 4\n' > "$H/partialuv.obj"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 3 0\nvt 0 1\nf 1/1 2/2 3/3\n' > "$H/uvrange.obj"
printf 'v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n' > "$H/nan.obj"
printf 'v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\nf 1 1 2\n' > "$H/degenerate.obj"
printf 'v 5 5 5\nv 5 5 5\nv 5 5 5\nf 1 2 3\n' > "$H/point.obj"
printf 'v 1e39 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n' > "$H/overflow.obj"
head -c 3000 /dev/urandom > "$H/garbage.obj"
printf 'glTF' > "$H/mesh.glb"
truncate -s 700M "$H/huge.obj"   # sparse: no disk used
mkdir -p "$H/folder.obj"
check_refused() {   # NAME FILE TEXT [paint options]
  local name=$1 file=$2 text=$3; shift 3
  expect 1 "refused: $name" -- $Q paint --mesh "$file" -p "a gold goblet" -o "$T/h_$name" "$@"
  err_has "$name: the file named" "$(basename "$file")"
  err_has "$name: the problem said" "$text"
  [ -e "$T/h_$name" ] && bad "$name: a run folder was written" || ok "$name: nothing written"
}
check_refused missing "$H/none.obj" "No such file"
check_refused empty "$H/empty.obj" "no faces"
check_refused nofaces "$H/nofaces.obj" "no faces"
check_refused badindex "$H/badindex.obj" "out of range"
check_refused baduvindex "$H/baduvindex.obj" "out of range"
check_refused partialuv "$H/partialuv.obj" "only some faces have UVs"
check_refused uvrange "$H/uvrange.obj" "outside \[0, 1\]"
check_refused nan "$H/nan.obj" "line 1"
check_refused degenerate "$H/degenerate.obj" "zero area"
check_refused point "$H/point.obj" "zero area"
check_refused overflow "$H/overflow.obj" "line 1"
check_refused garbage "$H/garbage.obj" "line"
check_refused glb "$H/mesh.glb" "truncated .glb"
check_refused huge "$H/huge.obj" "bytes"
check_refused folder "$H/folder.obj" "folder"

# ---- a cube with its own UVs, 37 units wide at (100, 50, -20) ----
cube() {   # one UV island per side in a 3 x 2 grid, quads (fanned by the reader), CCW from outside
  awk 'BEGIN {
    s = 37; ox = 100; oy = 50; oz = -20
    split("0 0 0,1 0 0,1 1 0,0 1 0,0 0 1,1 0 1,1 1 1,0 1 1", P, ",")
    for (i = 1; i <= 8; i++) { split(P[i], c, " "); printf "v %g %g %g\n", ox + s * c[1], oy + s * c[2], oz + s * c[3] }
    split("1 4 3 2,5 6 7 8,1 2 6 5,4 8 7 3,1 5 8 4,2 3 7 6", F, ",")
    for (k = 0; k < 6; k++) {
      u0 = (k % 3) / 3; v0 = int(k / 3) / 2
      printf "vt %g %g\nvt %g %g\nvt %g %g\nvt %g %g\n", u0+.02, v0+.02, u0+.31, v0+.02, u0+.31, v0+.48, u0+.02, v0+.48
    }
    for (k = 0; k < 6; k++) { split(F[k + 1], f, " "); printf "f"; for (j = 1; j <= 4; j++) printf " %d/%d", f[j], 4 * k + j; printf "\n" }
  }'
}
cube > "$T/cube.obj"
# a non-manifold edge and a zero-area face beside good ones are accepted (docs/paint.md)
{ cube; printf 'v 100 50 -20\nv 137 50 -20\nv 110 40 -40\nvt 0.5 0.9\nvt 0.6 0.9\nvt 0.5 0.95\nf 1/1 2/2 9/25\nf 1/1 1/1 2/2\n'; } > "$T/nonmanifold.obj"

small="--res 32 --views 2 --appearance-iters 4 --checkpoint-every 2 --preview-every 2 --export-texture 64"
expect 0 "paint the cube (project's model, tiny settings)" -- $Q paint --mesh "$T/cube.obj" -p "a red bowl" $small \
  --asset "$T/cube_out.obj" -o "$T/a"
for f in config.json loss.csv loss.png input/mesh.obj final/mesh.obj final/material.safetensors final/asset.glb \
         final/views.png previews/appearance_000004.png; do
  [ -s "$T/a/$f" ] && ok "run has $f" || bad "run lacks $f"
done
[ -e "$T/a/final/geometry.safetensors" ] && bad "a paint run wrote a geometry network" || ok "no geometry network"
grep -q '"paint_mesh"' "$T/a/config.json" && ok "config records the mesh" || bad "config lacks paint_mesh"
grep -q '"paint_scale"' "$T/a/config.json" && ok "config records the frame" || bad "config lacks paint_scale"
# counts: 24 corners (8 positions x their UVs), 12 triangles
n() { grep -c "^$1 " "$2"; }
[ "$(n v "$T/cube_out.obj")" = 24 ] && ok "24 vertices kept" || bad "vertices: $(n v "$T/cube_out.obj")"
[ "$(n vt "$T/cube_out.obj")" = 24 ] && ok "24 UVs kept" || bad "uvs: $(n vt "$T/cube_out.obj")"
[ "$(n f "$T/cube_out.obj")" = 12 ] && ok "12 faces kept" || bad "faces: $(n f "$T/cube_out.obj")"
# every corner (position, uv) of the output is one of the input's, and the other way round: the
# positions are back in the input's frame (scale and placement restored) and the UVs are the input's
corners() {   # OBJ -> sorted unique "x y z u v" of its face corners, 3 decimals
  awk '/^v /{n++; P[n]=sprintf("%.3f %.3f %.3f", $2, $3, $4)} /^vt /{m++; U[m]=sprintf("%.3f %.3f", $2, $3)}
       /^f /{for (i = 2; i <= NF; i++) { split($i, c, "/"); print P[c[1]], U[c[2]] }}' "$1" | sort -u
}
corners "$T/cube.obj" > "$T/in.txt"
corners "$T/cube_out.obj" > "$T/out.txt"
[ "$(wc -l < "$T/in.txt")" = 24 ] && cmp -s "$T/in.txt" "$T/out.txt" && ok "positions and UVs as in the input" \
  || { bad "corners differ"; diff "$T/in.txt" "$T/out.txt" | head; }
for f in cube_out.mtl cube_out_kd.png cube_out_ks.png cube_out_roughness.png; do
  [ -s "$T/$f" ] && ok "--asset wrote $f" || bad "--asset lacks $f"
done
[ "$(png_size "$T/cube_out_kd.png")" = "64x64" ] && ok "kd 64x64" || bad "kd size $(png_size "$T/cube_out_kd.png")"
# the .glb: the same counts (python3 reads its JSON chunk)
if command -v python3 > /dev/null; then
  expect 0 "glb counts" -- python3 -c '
import json, struct, sys
d = open(sys.argv[1], "rb").read()
n = struct.unpack("<I", d[12:16])[0]
g = json.loads(d[20:20 + n])
p = g["meshes"][0]["primitives"][0]
A = g["accessors"]
print(A[p["attributes"]["POSITION"]]["count"], A[p["attributes"]["TEXCOORD_0"]]["count"], A[p["indices"]]["count"] // 3,
      " ".join("%.3f" % v for v in A[p["attributes"]["POSITION"]]["min"] + A[p["attributes"]["POSITION"]]["max"]))
' "$T/a/final/asset.glb"
  grep -q "^24 24 12 100.000 50.000 -20.000 137.000 87.000 17.000$" "$T/out" && ok "glb: 24 vertices, 24 uvs, 12 faces, the input's box" \
    || bad "glb: $(cat "$T/out")"
else
  echo "skip: no python3 for the .glb check"
fi
# a .glb as input (docs/paint.md): the asset just written, painted again, keeps the cube's corners
grep -q '"appearance_guidance_scale":[[:space:]]*100,' "$T/a/config.json" && ok "the tiny preset paints at guidance 100" \
  || bad "config: appearance_guidance_scale not the preset's 100"
grep -q '"material_support":[[:space:]]*100,' "$T/a/config.json" && ok "the tiny preset holds the codes in the prior's support" \
  || bad "config: material_support not the preset's 100"
# paint has one stage: --guidance-scale alone is its scale, not overridden by the preset's appearance one
expect 0 "paint a .glb (our own asset)" -- $Q paint --mesh "$T/a/final/asset.glb" -p "a red bowl" $small --stop-after 1 \
  --guidance-scale 30 -o "$T/g"
grep -q '"guidance_scale":[[:space:]]*30,' "$T/g/config.json" && grep -q '"appearance_guidance_scale":[[:space:]]*0,' "$T/g/config.json" \
  && ok "paint --guidance-scale sets its one stage" || bad "paint --guidance-scale: $(grep guidance_scale "$T/g/config.json")"
corners "$T/g/input/mesh.obj" > "$T/g.txt"
cmp -s "$T/in.txt" "$T/g.txt" && ok ".glb input: positions and UVs as in the original OBJ" \
  || { bad ".glb input corners differ"; diff "$T/in.txt" "$T/g.txt" | head; }
# corrupt glTF refused, nothing written
head -c 2000 "$T/a/final/asset.glb" > "$H/truncated.glb"
LC_ALL=C sed 's/"POSITION"/"POSITIOM"/' "$T/a/final/asset.glb" > "$H/noposition.glb"
printf '{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}],"bufferViews":[{"buffer":0,"byteLength":36}],"buffers":[{"byteLength":36,"uri":"../secret.bin"}]}' > "$H/escape.gltf"
check_refused truncated_glb "$H/truncated.glb" "truncated"
check_refused noposition_glb "$H/noposition.glb" "no POSITION"
check_refused escape_gltf "$H/escape.gltf" "leaves the file's folder"

# matlaber export of a paint run: the same asset
expect 0 "export the paint run" -- $Q export "$T/a" --texture-size 64 -o "$T/exported.glb"
cmp -s "$T/exported.glb" "$T/a/final/asset.glb" && ok "export = final/asset.glb" || bad "export differs from final/asset.glb"

# --uv atlas: the project's atlas instead (more vertices: seams), faces kept
expect 0 "paint --uv atlas" -- $Q paint --mesh "$T/cube.obj" -p "a red bowl" $small --uv atlas --asset "$T/atlas.obj" -o "$T/c"
[ "$(n f "$T/atlas.obj")" = 12 ] && ok "atlas: 12 faces" || bad "atlas faces: $(n f "$T/atlas.obj")"
expect 0 "paint a non-manifold mesh with a zero-area face" -- $Q paint --mesh "$T/nonmanifold.obj" -p "a red bowl" $small -o "$T/nm"
err_has "zero-area face reported" "zero area"

# resume: stopped after 3 steps (checkpoint at 2), resumed, the same bytes as the uninterrupted run
expect 0 "paint stopped after 3 steps" -- $Q paint --mesh "$T/cube.obj" -p "a red bowl" $small -o "$T/b" --stop-after 3
[ -e "$T/b/final/asset.glb" ] && bad "stopped run has an asset" || ok "stopped run has no asset"
mv "$T/cube.obj" "$T/cube_moved.obj"   # the run keeps its own copy of the mesh
expect 0 "paint --resume (input file gone)" -- $Q --progress json paint --resume "$T/b"
mv "$T/cube_moved.obj" "$T/cube.obj"
for f in final/material.safetensors loss.csv final/asset.glb; do
  cmp -s "$T/a/$f" "$T/b/$f" && ok "resumed $f identical" || bad "resumed $f differs"
done
grep -q '^{"event":"begin","label":"paint","total":' "$T/err" && ok "json begin line" || bad "no json begin line"
grep -q '^{"event":"stage","label":"paint","stage":"appearance","index":3,"stages":5,"steps":4,"done":2}' "$T/err" \
  && ok "json stage line: the appearance stage resumed at its checkpoint, step 2" || bad "no json stage line of the resumed appearance stage"
grep -q '^{"event":"progress","label":"paint","stage":"appearance",.*"stage_done":4,"stage_steps":4,' "$T/err" \
  && ok "json progress line" || bad "no json progress line"
grep -q '^{"event":"result","command":"paint","finished":true,' "$T/err" && ok "json result line" || bad "no json result line"
expect 2 "generate --resume of a paint run" -- $Q generate --resume "$T/b"
err_has "names paint" "matlaber paint"
expect 1 "json error line" -- $M --progress json paint --mesh "$H/empty.obj" -p "a gold goblet" -o "$T/e"
grep -q '^{"event":"error","message":".*empty.obj' "$T/err" && ok "json error names the file" || bad "no json error line"
finish
