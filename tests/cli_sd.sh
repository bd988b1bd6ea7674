#!/usr/bin/env bash
# 'matlaber sd tokenize' end to end: help, exit codes, known ids with the real CLIP files.
set -u
M=${1:?usage: cli_sd.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
$M sd tokenize --help > /dev/null && ok "help" || bad "help"
$M sd tokenize -p "x" > /dev/null 2>&1; [ $? = 2 ] && ok "missing --tokenizer is a usage error" || bad "missing --tokenizer"
$M sd tokenize --tokenizer /nonexistent/tok -p "x" > /dev/null 2> /tmp/cli_sd_err.$$; rc=$?
[ $rc = 1 ] && grep -q "/nonexistent/tok" /tmp/cli_sd_err.$$ && ok "missing tokenizer names the path" || bad "missing tokenizer (exit $rc)"
rm -f /tmp/cli_sd_err.$$
D=${MLB_SHARED_DATA:-}
if [ -n "$D" ] && [ -d "$D/clip" ]; then
  for t in "$D/clip/bpe_simple_vocab_16e6.txt.gz" "$D/clip/tokenizer"; do
    out=$($M sd tokenize --tokenizer "$t" -p "a photo of a cat" | tr -s ' ,[]\n' ' ')
    echo "$out" | grep -q "49406 320 1125 539 320 2368 49407" && ok "known ids from $(basename $t)" || bad "ids from $t: $out"
  done
else
  echo "skip: no shared CLIP files"
fi
echo "$pass passed, $fail failed"
[ "$fail" = 0 ]
