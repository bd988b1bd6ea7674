#!/usr/bin/env bash
# 'matlaber sd tokenize' end to end: help, exit codes, known ids with the real CLIP files; 'sd train'
# (a very small model): its usage errors, and --resume refused with another option, the folder untouched.
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
T=$(mktemp -d /tmp/cli_sd_train.XXXXXX)
$M sd train --tiny --images 8 > /dev/null 2>&1; [ $? = 2 ] && ok "sd train without -o is a usage error" || bad "sd train without -o"
A="--tiny --images 8 --res 32 --vae-steps 1 --vae-batch 2 --unet-steps 2 --unet-batch 2"
$M --threads 2 sd train -o "$T/m" $A > /dev/null 2>&1 && [ -f "$T/m/model_index.json" ] && [ -f "$T/m/train/options.txt" ] \
  && ok "sd train writes the folder and its options" || bad "sd train (tiny)"
cp "$T/m/unet/diffusion_pytorch_model.safetensors" "$T/unet.before"
$M --threads 2 sd train -o "$T/m" $A --unet-steps 3 --resume > /dev/null 2> "$T/err"; rc=$?
[ $rc = 1 ] && grep -q "options.txt" "$T/err" && grep -q "unet_steps 2" "$T/err" && ok "--resume with another --unet-steps is refused, naming the option" \
  || bad "--resume with other options (exit $rc): $(cat "$T/err")"
cmp -s "$T/unet.before" "$T/m/unet/diffusion_pytorch_model.safetensors" && ok "the refused resume left the model as it was" || bad "the refused resume changed the model"
$M --threads 2 sd train -o "$T/m" $A --resume > /dev/null 2>&1 && cmp -s "$T/unet.before" "$T/m/unet/diffusion_pytorch_model.safetensors" \
  && ok "--resume of a finished run with its options gives the same UNet" || bad "--resume of a finished run"
rm -rf "$T"
echo "$pass passed, $fail failed"
[ "$fail" = 0 ]
