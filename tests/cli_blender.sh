#!/usr/bin/env bash
# The Blender add-on (tools/blender, docs/blender.md) with Debian's Blender in background mode: its
# zip installed through Blender's preferences operator, a mesh painted with the project's own model
# at tiny settings and imported, a run cancelled and resumed (tests/blender_addon.py has the checks);
# then metals rebuilt for Principled BSDF after the import (tests/blender_metals.py).
# Skipped (77) without blender; scripts/install-deps.sh installs it, so CI runs it.
set -u
M=${1:?usage: cli_blender.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
HERE=$(cd "$(dirname "$0")" && pwd)
command -v blender > /dev/null || { echo "skip: blender not installed (scripts/install-deps.sh)"; exit 77; }
command -v python3 > /dev/null || { echo "skip: no python3 to build the add-on's zip"; exit 77; }
M=$(cd "$(dirname "$M")" && pwd)/$(basename "$M")
expect 0 "the add-on's zip" -- python3 "$HERE/../tools/blender/make_zip.py" "$T/matlaber_blender.zip"
# Blender's user folders inside the scratch folder: the install does not touch ~/.config/blender
export BLENDER_USER_CONFIG="$T/config" BLENDER_USER_SCRIPTS="$T/scripts" BLENDER_USER_DATAFILES="$T/datafiles"
blender -b --factory-startup --python-exit-code 1 --python "$HERE/blender_addon.py" -- "$M" "$T/matlaber_blender.zip" \
  > "$T/blender.log" 2>&1
rc=$?
grep -E "^(ok|FAIL) |^status:|[0-9]+ failed$" "$T/blender.log"
if [ $rc = 0 ]; then ok "blender add-on test"; else bad "blender add-on test (exit $rc)"; tail -40 "$T/blender.log"; fi
[ -d "$T/scripts/addons/matlaber_blender" ] && ok "installed into BLENDER_USER_SCRIPTS" || bad "not installed where expected"

# Metals rebuilt for Blender's Principled BSDF (tests/blender_metals.py): the catalogue's gold and red
# goblets (known BRDFs), and test_export's sphere (dielectric and gold texels in one material) when built
expect 0 "the catalogue's gold goblet as .glb" -- "$M" catalogue export --class goblet --material gold -o "$T/gold.glb"
expect 0 "the catalogue's red goblet as .glb" -- "$M" catalogue export --class goblet --material red -o "$T/red.glb"
W="$(dirname "$M")/tests/test_export"
SPHERE=-
if [ -x "$W" ] && "$W" --write-glb "$T/sphere.glb" > /dev/null 2>&1; then SPHERE="$T/sphere.glb"; fi
blender -b --factory-startup --python-exit-code 1 --python "$HERE/blender_metals.py" -- "$M" "$T/matlaber_blender.zip" \
  "$T/gold.glb" "$T/red.glb" "$SPHERE" > "$T/metals.log" 2>&1
rc=$?
grep -E "^(ok|FAIL|skip) |[0-9]+ failed$" "$T/metals.log"
if [ $rc = 0 ]; then ok "blender metals test"; else bad "blender metals test (exit $rc)"; tail -40 "$T/metals.log"; fi
finish
