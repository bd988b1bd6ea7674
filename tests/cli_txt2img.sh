#!/usr/bin/env bash
# 'matlaber sd txt2img' end to end: help, usage and load errors with their exit codes, the project's
# own model without -m, and (with ../shared/data) a 128x128 PNG from the tiny SD1 fixture in both layouts.
set -u
M=${1:?usage: cli_txt2img.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"

expect 0 "help" -- $M sd txt2img --help
expect 0 "sd help lists txt2img" -- $M sd --help
grep -q txt2img "$T/out" && ok "txt2img in sd --help" || bad "txt2img missing from sd --help"
expect 1 "no -m, \$MATLABER_MODEL missing" -- env MATLABER_MODEL=/nonexistent/own $M sd txt2img -p x -o "$T/a.png"
err_has "the missing default named" "/nonexistent/own"
expect 2 "missing -p" -- $M sd txt2img -m /x -o "$T/a.png"
expect 2 "missing -o" -- $M sd txt2img -m /x -p x
expect 2 "bad --size" -- $M sd txt2img -m /x -p x -o "$T/a.png" --size 100
expect 2 "bad --steps" -- $M sd txt2img -m /x -p x -o "$T/a.png" --steps 0
expect 1 "pickle refused" -- $M sd txt2img -m "$T/model.ckpt" -p x -o "$T/a.png"
err_has "pickle hint" "convert it to .safetensors"
expect 1 "missing model" -- $M sd txt2img -m /nonexistent/sd.safetensors -p x -o "$T/a.png"
err_has "missing model named" "/nonexistent/sd.safetensors"
# a safetensors file without the model's tensors: the missing tensor is named
printf '\x10\x00\x00\x00\x00\x00\x00\x00{}              ' > "$T/empty.safetensors"
expect 1 "empty checkpoint" -- $M sd txt2img -m "$T/empty.safetensors" -p x -o "$T/a.png"
err_has "empty checkpoint names the file" "empty.safetensors"
[ -e "$T/a.png" ] && bad "no output after errors" || ok "no output after errors"
# bf16 asked for by name where the CPU cannot: one warning; a preset's own bf16 (no option) says nothing
expect 0 "--precision bf16 without the CPU's bf16" -- env MATLABER_CPU_BF16=0 $M --device cpu --precision bf16 device
# (the reason: "off ($MATLABER_CPU_BF16)" on a CPU that has it, "this CPU has no AVX-512 BF16" elsewhere)
err_has "the fallback warned" "warn. --precision bf16: [^;]*; the CPU computes in fp32"
[ "$(grep -c 'precision bf16' "$T/err")" = 1 ] && ok "said once" || bad "said $(grep -c 'precision bf16' "$T/err") times"
expect 0 "no --precision" -- env MATLABER_CPU_BF16=0 $M --device cpu device
grep -q 'warn' "$T/err" && bad "a warning without --precision: $(cat "$T/err")" || ok "no warning without --precision"
grep -q '^bf16 GEMM.*: fp32 here' "$T/out" && ok "device: bf16 off said" || bad "device: $(grep '^bf16' "$T/out")"
# the kernel `device` names: AMX tiles only where the CPU has them and $MATLABER_CPU_AMX allows
expect 0 "device, AMX off" -- env MATLABER_CPU_AMX=0 $M device
grep -q '^bf16 GEMM.*AMX tiles' "$T/out" && bad "AMX named though off: $(grep '^bf16' "$T/out")" || ok "device: AMX off not named"
expect 0 "device" -- env -u MATLABER_CPU_AMX -u MATLABER_CPU_BF16 $M device
if grep -q 'amx_bf16' "$T/out" && grep -q 'avx512_bf16' "$T/out"; then
  grep -q '^bf16 GEMM.*: AMX tiles' "$T/out" && ok "device: AMX tiles on an AMX CPU" || bad "device on an AMX CPU: $(grep '^bf16' "$T/out")"
fi

# no -m: the project's own model that draws shaded objects (models/matlaber-tiny-appearance, else
# models/matlaber-tiny), at the 128x128 it was trained at
expect 0 "no -m: the project's own model" -- env -u MATLABER_MODEL -u MATLABER_APPEARANCE_MODEL $M sd txt2img -p "a gold goblet" --steps 2 -o "$T/own.png"
[ "$(png_size "$T/own.png")" = "128x128" ] && ok "own model: 128x128 PNG" || bad "own model: PNG size $(png_size "$T/own.png" 2>/dev/null)"
OWN=$(dirname "$0")/../models
if [ -f "$OWN/matlaber-tiny-appearance/model_index.json" ]; then
  expect 0 "-m the appearance model" -- $M sd txt2img -m "$OWN/matlaber-tiny-appearance" -p "a gold goblet" --steps 2 --size 128 --cfg 3 -o "$T/app.png"
  cmp -s "$T/own.png" "$T/app.png" && ok "no -m samples the appearance model" || bad "no -m: not the appearance model's image"
  expect 0 "\$MATLABER_MODEL: that model" -- env -u MATLABER_APPEARANCE_MODEL MATLABER_MODEL="$OWN/matlaber-tiny" $M sd txt2img -p "a gold goblet" --steps 2 -o "$T/geo.png"
  expect 0 "-m the geometry model" -- $M sd txt2img -m "$OWN/matlaber-tiny" -p "a gold goblet" --steps 2 --size 128 --cfg 3 -o "$T/geo2.png"
  cmp -s "$T/geo.png" "$T/geo2.png" && ok "\$MATLABER_MODEL replaces both defaults" || bad "\$MATLABER_MODEL: another model's image"
  cmp -s "$T/own.png" "$T/geo.png" && bad "the two models drew the same image" || ok "the two models draw differently"
fi
expect 0 "sd tokenize with the own model's tokenizer" -- $M sd tokenize -t "$(dirname "$0")/../models/matlaber-tiny" -p "a gold goblet"
grep -q "padded with 633 (sd1)" "$T/out" && ok "sd1 pads with the small vocabulary's end token" || bad "padding: $(grep padded "$T/out")"

D=${MLB_SHARED_DATA:-$(dirname "$0")/../../shared/data}
R="$D/sd_reference"
if [ -d "$R/sd1_diffusers" ]; then
  expect 0 "tiny diffusers folder, 128x128" -- $M sd txt2img -m "$R/sd1_diffusers" -p "a golden goblet" --steps 4 --cfg 7.5 --size 128 --seed 3 -o "$T/a.png"
  [ "$(png_size "$T/a.png")" = "128x128" ] && ok "128x128 PNG" || bad "PNG size $(png_size "$T/a.png" 2>/dev/null)"
  expect 0 "same seed again" -- $M sd txt2img -m "$R/sd1_diffusers" -p "a golden goblet" --steps 4 --size 128 --seed 3 -o "$T/b.png"
  cmp -s "$T/a.png" "$T/b.png" && ok "deterministic" || bad "same seed gave a different image"
  expect 1 "single file without a tokenizer" -- env -u MATLABER_TOKENIZER $M sd txt2img -m "$R/sd1_tiny.safetensors" -p x --size 64 --steps 1 -o "$T/c.png"
  err_has "tokenizer hint" "tokenizer"
  expect 0 "single file + tokenizer folder" -- $M sd txt2img -m "$R/sd1_tiny.f16.safetensors" --tokenizer "$R/sd1_diffusers/tokenizer" -p "a golden goblet" --negative "low quality" --steps 2 --size 64 -o "$T/c.png"
  [ "$(png_size "$T/c.png")" = "64x64" ] && ok "64x64 PNG" || bad "PNG size"
  # --precision on the CPU: the default (fp16, a GPU format) and fp32 are the same fp32 image; bf16
  # runs (its linear and conv GEMMs in bf16 where the CPU has AVX-512 BF16) and says so
  P=(sd txt2img -m "$R/sd1_diffusers" -p "a golden goblet" --steps 2 --size 64 --seed 5)
  expect 0 "cpu, default precision" -- $M --device cpu "${P[@]}" -o "$T/p16.png"
  expect 0 "cpu, --precision fp32" -- $M --device cpu --precision fp32 "${P[@]}" -o "$T/p32.png"
  cmp -s "$T/p16.png" "$T/p32.png" && ok "cpu: default = fp32, bit for bit" || bad "cpu: the default precision changed the image"
  expect 0 "cpu, --precision bf16" -- $M --log-level info --device cpu --precision bf16 "${P[@]}" -o "$T/pbf.png"
  [ "$(png_size "$T/pbf.png")" = "64x64" ] && ok "bf16: 64x64 PNG" || bad "bf16: PNG size"
  err_has "bf16 said in the log" "bf16"
else
  echo "skip: no shared sd_reference fixtures"
fi
echo "$pass passed, $fail failed"
[ "$fail" = 0 ]
