#!/usr/bin/env bash
# matlaber demo --fit --quick end to end: the procedural goblet fitted from its own renders, its report's
# measures within bounds of what the quick fit reaches (measured: Chamfer 0.0022, normal error 5.0°,
# albedo 20.6 dB, relighting 27.1 dB), and its side-by-side images. The fit is deterministic, so the
# bounds only leave room for other CPUs' BLAS rounding. Plain build only: under the sanitizers the same
# fit code runs in cli_pipeline, and this one takes minutes there.
set -u
M=${1:?usage: cli_demo.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
if [ "${MLB_TEST_SANITIZED:-0}" = 1 ]; then echo "skip: the quick demo fit is left to the plain build"; exit 77; fi

expect 0 "demo --fit --quick" -- $M --log-level warn demo --fit --quick -o "$T/d"
row=$(grep '^| latent |' "$T/d/report.md")
[ -n "$row" ] && ok "report has the latent row" || bad "report lacks the latent row"
# | latent | chamfer | normal° | albedo dB | train dB | relight dB | seconds |
IFS='|' read -r _ _ chamfer normal albedo train relight _ <<< "$(echo "$row" | tr -d ' °dB')"
within() { awk -v x="$2" -v lo="$3" -v hi="$4" 'BEGIN { exit !(x + 0 == x && x >= lo && x <= hi) }' && ok "$1 $2 in [$3, $4]" || bad "$1 $2 not in [$3, $4]"; }
within "Chamfer / diagonal" "$chamfer" 0 0.004
within "normal error (deg)" "$normal" 0 6.5
within "albedo PSNR (dB)" "$albedo" 18 99
within "training light PSNR (dB)" "$train" 24 99
within "relighting PSNR (dB)" "$relight" 24 99
for f in compare_latent_train.png compare_latent_relit.png fit_latent/final/asset.glb; do
  [ -s "$T/d/$f" ] && ok "demo wrote $f" || bad "demo lacks $f"
done
[ "$(head -c 4 "$T/d/fit_latent/final/asset.glb")" = "glTF" ] && ok "the asset is a .glb" || bad "the asset is not a .glb"
finish
