#!/usr/bin/env bash
# 'matlaber bench text3d': help, usage errors that name the bad value, and exit codes (the whole path
# runs in test_text3d on the tiny SD fixture); with the project's own model, one prompt in a held-out
# phrasing (--phrasing) cut to a step per stage: read as its caption, the caption's run bit for bit.
set -u
M=${1:?usage: cli_bench.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"

expect 0 "bench --help" -- $M bench --help
expect 0 "bench text3d --help" -- $M bench text3d --help
grep -q -- "--steps-scale" "$T/out" && grep -q -- "--no-view-prompts" "$T/out" && grep -q -- "--phrasing" "$T/out" && ok "help lists the options" || bad "help: $(cat "$T/out")"
expect 2 "no benchmark named" -- $M bench
expect 2 "unknown benchmark" -- $M bench nope
expect 2 "unknown class" -- $M bench text3d --classes goblet,nope --model /nonexistent
err_has "the error names the class" "unknown class 'nope'"
expect 2 "unknown material" -- $M bench text3d --materials plastic --model /nonexistent
err_has "the error names the material" "plastic"
expect 2 "bad steps scale" -- $M bench text3d --steps-scale 0 --model /nonexistent
expect 2 "bad shape fit" -- $M bench text3d --shape-fit -1 --model /nonexistent
err_has "the error names the option" "--shape-fit"
expect 2 "bad preset" -- $M bench text3d --preset huge --model /nonexistent
err_has "the error names the presets" "tiny"
expect 1 "a missing model fails" -- $M bench text3d --classes bowl --materials gold --model "$T/none" -o "$T/b"
expect 2 "bad phrasing" -- $M bench text3d --phrasing 6 --model /nonexistent
err_has "the error names the option" "--phrasing: expected 0..5 or mixed"

OWN=$(dirname "$0")/../models
if [ -f "$OWN/matlaber-tiny/model_index.json" ]; then
  B=(--pairs mug:copper --steps-scale 0.01 --shape-seeds 1 --shape-fit 0 --init ellipsoid --set material_start=0
     --set init_iters=10 --set views=1 --set res=32 --set grid=16 --set hash_table_log2=12)
  expect 0 "the catalogue's caption" -- env -u MATLABER_MODEL -u MATLABER_APPEARANCE_MODEL $M --log-level warn bench text3d "${B[@]}" -o "$T/c"
  expect 0 "--phrasing 5" -- env -u MATLABER_MODEL -u MATLABER_APPEARANCE_MODEL $M --log-level warn bench text3d "${B[@]}" --phrasing 5 -o "$T/p"
  grep -q "^| a mug of copper | held out |" "$T/out" && ok "the row carries the phrasing" || bad "row: $(grep '^| a' "$T/out")"
  grep -q '"caption":[[:space:]]*"a copper mug"' "$T/p/mug_copper/config.json" && ok "read as its caption" || bad "config: no caption"
  for f in final/mesh.obj final/material.safetensors; do
    cmp -s "$T/c/mug_copper/$f" "$T/p/mug_copper/$f" && ok "$f: the caption's, bit for bit" || bad "$f differs from the caption's"
  done
  expect 1 "a phrasing into the caption's folder" -- env -u MATLABER_MODEL -u MATLABER_APPEARANCE_MODEL $M --log-level warn bench text3d "${B[@]}" --phrasing 2 -o "$T/c"
  err_has "refused as another prompt" "a run made with another prompt"
fi
finish
