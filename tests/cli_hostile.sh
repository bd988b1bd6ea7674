#!/usr/bin/env bash
# Hostile input to the command line (docs/files.md, "What each input may be"): each case ends in a
# clear error naming the input and the problem, or in correct output, with nothing left behind.
set -u
M=${1:?usage: cli_hostile.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
Q="$M --log-level warn"

# --prompts: the command line's words and a line's options go whole into each prompt's generate,
# however many (340 words before and 32 option pairs on the line once overran a fixed vector on the
# stack). The last word, an invalid --res, must reach generate: it fails at once, naming it.
many=$(printf -- '--seed 1 %.0s' $(seq 170))
printf -- '--seed 2 %.0s' $(seq 32) > "$T/p.txt"
echo 'a gold goblet' >> "$T/p.txt"
expect 1 "--prompts: 340 words on the command line, 32 option pairs on the line" -- $Q generate $many --res 7 --prompts "$T/p.txt" -o "$T/many"
err_has "the command line's last word reached generate" "res: expected a multiple of 8"
grep -q '"status":[[:space:]]*"failed"' "$T/many/summary.json" && ok "summary.json: the prompt failed" || bad "summary.json: not failed"
[ -e "$T/many/.claims" ] && bad "claims left behind" || ok "no claims left behind"

finish
