#!/usr/bin/env bash
# The folders of src/ are layers (docs/architecture.md "Layers"): a file may include headers of its
# own folder and of the folders below it, never of one above, so there is no upward include and no
# include circle between folders. This walks every #include "..." of src/ and include/matlaber/ and
# fails naming each include that goes up, and each call below the program to the global device or
# precision (which the program passes down instead). With a build folder it also reads the library's object
# files (tests/check_calls.sh): no files of src/ that call each other in a loop, no function declared
# in a folder below the one that defines it. Usage: tests/check_layout.sh [repository root [build folder]]
set -euo pipefail
build_dir=""
if [ -n "${2:-}" ]; then build_dir=$(cd "$2" && pwd); fi
cd "${1:-$(dirname "$0")/..}"

# Lowest first. views: the cameras and image sets the guidance sees and the catalogue renders;
# catalogue: the procedural truth (shapes, materials, captions) the pipeline reads prompts against;
# training (the project's own diffusion model) and benchmark (text-to-3D) run on the pipeline.
# cuda is the top: its kernels implement the op list (cuda_ops.h) that nn declares.
order="core mesh io render nn brdf field geometry export diffusion views catalogue pipeline training benchmark cuda"

# The owner of a public header include/matlaber/X.h is the folder of src/*/X.c; headers without a
# same-named source say here which folder they belong to (an interface belongs to the lowest folder
# that consumes it; its implementations may sit above). A header missing from both fails the check.
declare -A owner=(
  [brdf.h]=brdf [cameras.h]=views [cuda_ops.h]=nn [backend_ops.def]=nn [dmtet.h]=geometry
  [export.h]=export [geometry.h]=geometry [guidance.h]=geometry [gltf.h]=io [nn.h]=nn [paint.h]=pipeline
  [raster.h]=render [unet_train.h]=diffusion
  [brdf_ae_api.inc]=brdf [hashgrid_api.inc]=nn [nn_api.inc]=nn [raster_api.inc]=render [vae_api.inc]=diffusion
)

declare -A rank=()
i=0
for f in $order; do rank[$f]=$i; i=$((i + 1)); done

owner_of() {   # path -> folder, or empty
  local p=$1 b n s
  case $p in
    src/*/*) p=${p#src/}; echo "${p%%/*}"; return ;;
    include/matlaber/*)
      b=${p#include/matlaber/}
      if [ -n "${owner[$b]:-}" ]; then echo "${owner[$b]}"; return; fi
      n=${b%.*}
      for s in src/*/"$n".c; do
        if [ -f "$s" ]; then s=${s#src/}; echo "${s%%/*}"; return; fi
      done ;;
  esac
}

bad=0
for d in src/*/; do
  d=${d#src/}; d=${d%/}
  if [ -z "${rank[$d]:-}" ]; then echo "check_layout: src/$d is not in the order (tests/check_layout.sh)"; bad=1; fi
done
while IFS= read -r file; do
  from=$(owner_of "$file")
  if [ -z "$from" ]; then echo "check_layout: $file: no owner folder (add it to tests/check_layout.sh)"; bad=1; continue; fi
  dir=$(dirname "$file")
  while IFS=: read -r line inc; do
    # "matlaber/x.h" is include/matlaber/x.h; "folder/x.h" is src/folder/x.h; "x.h" is beside the file
    case $inc in
      matlaber/*) target=include/$inc ;;
      */*) target=src/$inc ;;
      *) target=$dir/$inc ;;
    esac
    [ -f "$target" ] || { echo "check_layout: $file:$line: includes \"$inc\", which is not in the tree"; bad=1; continue; }
    to=$(owner_of "$target")
    if [ -z "$to" ]; then echo "check_layout: $target: no owner folder (add it to tests/check_layout.sh)"; bad=1; continue; fi
    if [ "${rank[$to]}" -gt "${rank[$from]}" ]; then
      echo "check_layout: $file:$line: $from includes $inc ($to), a folder above it (order: $order)"
      bad=1
    fi
  done < <(grep -n '^[[:space:]]*#[[:space:]]*include[[:space:]]*"' "$file" | sed 's/^\([0-9]*\):.*"\([^"]*\)".*/\1:\2/')
done < <(find src include/matlaber -type f \( -name '*.c' -o -name '*.h' -o -name '*.cu' -o -name '*.cuh' -o -name '*.inc' -o -name '*.def' \) | sort)

# One device passed down: the program (tools/matlaber) alone reads --device and --precision and
# hands the choice to what it runs (mlb_pipeline_run's and mlb_pipeline_make_guidance's table,
# mlb_sd_model_options). Below it nothing reads or sets the program's global device or precision:
# src/core/device.c and precision.c, which hold them, are the only files of src/ that name them.
globals='mlb_device_current|mlb_device_select|mlb_device_option|mlb_gemm_precision_current|mlb_gemm_precision_chosen|mlb_set_gemm_precision'
while IFS= read -r hit; do
  code=${hit#*:*:}; code=${code%%//*}   # a comment may name them
  if [[ $code =~ ($globals)[[:space:]]*\( ]]; then
    echo "check_layout: ${hit%%:*}: calls ${BASH_REMATCH[1]}: a stage is given its device (a backend or options field set by the program), it never reads the program's"
    bad=1
  fi
done < <(grep -rnE "($globals)[[:space:]]*\(" src | grep -vE '^src/core/(device|precision)\.c:' || true)

if [ $bad -ne 0 ]; then exit 1; fi
echo "check_layout: no upward include among src/ folders ($order); no global device read below the program"
if [ -n "$build_dir" ]; then
  source tests/check_calls.sh
  check_calls "$build_dir"
else
  echo "check_layout: no build folder given: the call check (tests/check_calls.sh) did not run"
fi
