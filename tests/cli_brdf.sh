#!/usr/bin/env bash
# The program's brdf commands end to end: help, exit codes, error messages, a tiny training run,
# a file round trip, encode/decode, interp and the JSON output.
set -u
M=${1:?usage: cli_brdf.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"

for c in "" "brdf" "brdf train" "brdf eval" "brdf encode" "brdf decode" "brdf interp" "demo" "device"; do
  expect 0 "help: $c" -- $M $c --help
done
expect 2 "unknown command" -- $M frobnicate
expect 2 "unknown brdf subcommand" -- $M brdf frobnicate
expect 2 "bad epochs" -- $M brdf train --epochs zero
err_has "bad epochs message" "--epochs"
expect 2 "encode wrong count" -- $M brdf encode --k 1,2,3
expect 2 "encode invalid BRDF" -- $M brdf encode --k 0.5,0.5,0.5,0.04,0.04,0.04,2
err_has "invalid BRDF message" "not a valid BRDF"
expect 2 "interp needs ends" -- $M brdf interp --from-k 0.5,0.5,0.5,0.04,0.04,0.04,0.5

# missing and corrupt model files: exit 1, message names the file
expect 1 "missing model" -- $M brdf decode --model "$T/nope.safetensors" --z 0,0,0,0
err_has "missing model names the file" "nope.safetensors"
printf 'not a safetensors file at all' > "$T/junk.safetensors"
expect 1 "corrupt model" -- $M brdf decode --model "$T/junk.safetensors" --z 0,0,0,0
err_has "corrupt model names the file" "junk.safetensors"
expect 1 "missing data folder" -- $M brdf train --data "$T/no_such_dir" --epochs 1 --out "$T/x.safetensors"
err_has "missing data names the folder" "no_such_dir"
[ ! -e "$T/x.safetensors" ] && ok "failed training writes nothing" || bad "failed training left a file"

# a tiny training run, its file, and the commands on it
expect 0 "tiny training" -- $M --log-level warn brdf train --samples 4000 --epochs 2 --batch 64 --lr 3e-3 --out "$T/p.safetensors" --json
grep -q '"parameters"' "$T/out" && ok "train --json" || bad "train --json"
expect 0 "decode with the trained model" -- $M brdf decode --model "$T/p.safetensors" --z 0,0,0,0
n=$(wc -w < "$T/out"); [ "$n" = 7 ] && ok "decode prints 7 numbers" || bad "decode printed $n numbers"
expect 0 "eval --json" -- $M brdf eval --model "$T/p.safetensors" --samples 3000 --json
grep -Eq '"interp_valid_share":[[:space:]]*1,' "$T/out" && ok "every interpolated BRDF valid" || { bad "interp validity"; cat "$T/out"; }
expect 0 "stdin rows" -- bash -c "printf '0.5 0.4 0.3 0.04 0.04 0.04 0.5\n\n0.9,0.1,0.1,0.04,0.04,0.04,0.3\n' | $M brdf encode --model $T/p.safetensors"
[ "$(wc -l < "$T/out")" = 2 ] && ok "one code per stdin row" || bad "stdin rows: $(cat "$T/out")"
expect 0 "interp" -- $M brdf interp --model "$T/p.safetensors" --from-z -1,0,0,0 --to-z 1,0,0,0 --steps 5
[ "$(grep -vc '^#' "$T/out")" = 5 ] && ok "interp prints 5 rows" || bad "interp rows"

# the built-in prior: encode then decode comes back close for a typical material
if $M brdf decode --z 0,0,0,0 > /dev/null 2>&1; then
  z=$($M brdf encode --k 0.6,0.3,0.2,0.04,0.04,0.04,0.5 | tr ' ' ',')
  k=$($M brdf decode --z "$z")
  echo "$k" | awk '{d=($1-0.6)^2+($2-0.3)^2+($3-0.2)^2+($4-0.04)^2+($5-0.04)^2+($6-0.04)^2+($7-0.5)^2; exit !(sqrt(d) < 0.1)}' \
    && ok "built-in prior round trip within 0.1" || bad "built-in prior round trip: $k"
  # gold (a metal at the edge of the distribution): the refined code decodes to it closely
  gold=0,0,0,1,0.766,0.336,0.3
  k=$($M brdf decode --z "$($M brdf encode --k $gold | tr ' ' ',')")
  echo "$k" | awk '{d=$1^2+$2^2+$3^2+($4-1)^2+($5-0.766)^2+($6-0.336)^2+($7-0.3)^2; exit !(sqrt(d) < 0.03)}' \
    && ok "gold round trip with refinement within 0.03" || bad "gold round trip: $k"
  expect 2 "refine is for encode" -- $M brdf decode --refine 3 --z 0,0,0,0
  MATLABER_PRIOR="$T/junk.safetensors" $M brdf decode --z 0,0,0,0 > /dev/null 2> "$T/err"
  [ $? = 1 ] && grep -q "MATLABER_PRIOR" "$T/err" && ok "bad \$MATLABER_PRIOR is an error" || bad "bad \$MATLABER_PRIOR"
else
  echo "skip: this build has no built-in prior"
fi

echo "$pass passed, $fail failed"
[ "$fail" = 0 ]
