#!/usr/bin/env bash
# 'matlaber bench text3d': help, usage errors that name the bad value, and exit codes (no generation:
# the whole path runs in test_text3d on the tiny SD fixture).
set -u
M=${1:?usage: cli_bench.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"

expect 0 "bench --help" -- $M bench --help
expect 0 "bench text3d --help" -- $M bench text3d --help
grep -q -- "--steps-scale" "$T/out" && grep -q -- "--no-view-prompts" "$T/out" && ok "help lists the options" || bad "help: $(cat "$T/out")"
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
finish
