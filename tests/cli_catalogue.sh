#!/usr/bin/env bash
# 'matlaber catalogue list | export | render': outputs, OBJ contents, PNG sizes, captions, exit codes,
# and errors that name the unknown class or material.
set -u
M=${1:?usage: cli_catalogue.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"

expect 0 "catalogue --help" -- $M catalogue --help
expect 0 "catalogue list --help" -- $M catalogue list --help
expect 0 "catalogue export --help" -- $M catalogue export --help
expect 0 "catalogue render --help" -- $M catalogue render --help
expect 0 "list" -- $M catalogue list
grep -q "a silver goblet" "$T/out" && ok "list shows the held-out pairs" || bad "list: $(cat "$T/out")"
expect 0 "list --json" -- $M catalogue list --json
if command -v python3 > /dev/null; then
  python3 -c "import json,sys; d=json.load(open(sys.argv[1])); assert len(d['classes'])>=8 and len(d['materials'])>=6 and len(d['held_out'])>=8; assert all(len(m['brdf'])==7 for m in d['materials'])" "$T/out" \
    && ok "list --json parses" || bad "list --json: $(head -c 300 "$T/out")"
fi
expect 0 "export a mug" -- $M catalogue export --class mug --seed 3 -o "$T/mug.obj"
nv=$(grep -c '^v ' "$T/mug.obj"); nn=$(grep -c '^vn ' "$T/mug.obj"); nf=$(grep -c '^f ' "$T/mug.obj")
[ "$nv" -gt 500 ] && [ "$nv" = "$nn" ] && [ "$nf" -gt 1000 ] && ok "OBJ has v, vn, f ($nv, $nn, $nf)" || bad "OBJ counts $nv $nn $nf"
awk '/^v /{r=sqrt($2*$2+$3*$3+$4*$4); if (r>0.9001) b++} END{exit b>0}' "$T/mug.obj" && ok "vertices within radius 0.9" || bad "vertices outside 0.9"
# the handle is on +x: the bounding box is centred, so the cup's rim (its top vertices) sits on -x
awk '/^v /{n++; x[n]=$2; y[n]=$3; if ($3>ym) ym=$3} END{for(i=1;i<=n;i++) if (y[i]>ym-0.01) {s+=x[i]; c++}; exit !(c>0 && s/c < -0.05)}' "$T/mug.obj" \
  && ok "the mug's handle is on +x" || bad "handle side"
expect 0 "the exported OBJ loads back" -- $M render --mesh "$T/mug.obj" --size 16 --cube 64 --supersample 1 -o "$T/mug.png"
expect 0 "render 3 views" -- $M catalogue render --class goblet --material gold --views 3 --res 32 -o "$T/r"
[ "$(png_size "$T/r/rgb_002.png")" = "32x32" ] && [ "$(png_size "$T/r/normal_002.png")" = "32x32" ] && ok "PNGs 32x32" || bad "PNG sizes"
grep -q '"caption": "a gold goblet, front view"' "$T/r/captions.json" && grep -q '"caption": "a gold goblet, side view"' "$T/r/captions.json" \
  && ok "captions with the view suffixes" || bad "captions: $(cat "$T/r/captions.json")"
expect 0 "render orbit views" -- $M catalogue render --class table --material stone --seed 4 --orbit --views 2 --res 32 -o "$T/o"
[ -s "$T/o/rgb_001.png" ] && ok "orbit views written" || bad "orbit views missing"

# errors
expect 2 "unknown subcommand" -- $M catalogue draw
expect 2 "export needs --class" -- $M catalogue export -o "$T/x.obj"
expect 2 "render needs -o" -- $M catalogue render --class mug --material red
expect 1 "unknown class" -- $M catalogue export --class spaceship -o "$T/x.obj"
err_has "unknown class names it" "spaceship"
err_has "unknown class lists the classes" "goblet"
expect 1 "unknown material" -- $M catalogue render --class mug --material plutonium -o "$T/x"
err_has "unknown material names it" "plutonium"
expect 2 "bad --env" -- $M catalogue render --class mug --material red --env moon -o "$T/x"
[ ! -e "$T/x.obj" ] && [ ! -e "$T/x" ] && ok "failures write nothing" || bad "a failure left an output"
finish
