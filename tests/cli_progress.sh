#!/usr/bin/env bash
# What a person meets first: an empty or blank prompt refused at once with a sentence ("a prompt is
# required") and no run folder, and --progress json's stages (shape start, geometry, material start,
# appearance, export) of a small generate with the project's own model: in order, each step counted
# in its stage, no losses in the status at the default log level, and the run's duration as its
# first ETA foretold it (the time until then plus the ETA) within a factor of 2 of the real one
# (docs/usage.md, "Progress").
set -u
M=${1:?usage: cli_progress.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
command -v python3 > /dev/null || { echo "skip: no python3 to read the JSON lines"; exit 77; }

for p in "" "   " "$(printf ' \t ')"; do
  expect 2 "generate -p '$p' refused" -- $M generate -p "$p" -o "$T/blank"
  err_has "says a prompt is required" "a prompt is required"
  [ -e "$T/blank" ] && bad "a run folder was made for a blank prompt" || ok "no run folder"
done
expect 2 "paint with a blank prompt refused" -- $M paint --mesh "$T/none.obj" -p "  " -o "$T/blank"
err_has "paint says a prompt is required" "a prompt is required"
[ -e "$T/blank" ] && bad "paint made a run folder" || ok "paint: no run folder"
expect 2 "generate without a prompt" -- $M generate -o "$T/blank"
err_has "says a prompt is required" "a prompt is required"
expect 2 "json: the error line" -- $M --progress json generate -p " " -o "$T/blank"
grep -q '^{"event":"error","usage":true,"message":"a prompt is required' "$T/err" && ok "json error line" || bad "no json error line"

[ -d "$(dirname "$0")/../models/matlaber-tiny" ] || { echo "skip: the project's own model is not there"; finish; exit $?; }
# 40 fit steps: at 20 the tiny preset's coarse geometry hash grid leaves an SDF that 32² guidance erases
expect 0 "generate --progress json, a few steps per stage" -- $M --progress json generate -p "a red vase" --init ellipsoid \
  --init-iters 40 --geometry-iters 10 --appearance-iters 8 --res 32 --views 1 --export-texture 32 --preview-every 0 -o "$T/g"
python3 - "$T/err" <<'PY' && ok "the progress stream's stages and ETA" || bad "the progress stream (above)"
import json, sys
ev = [json.loads(l) for l in open(sys.argv[1]) if l.startswith("{")]
names = ["shape start", "geometry", "material start", "appearance", "export"]
bad = []
plan = [e for e in ev if e["event"] == "plan"]
if len(plan) != 1 or [s["name"] for s in plan[0]["stages"]] != names:
    bad.append("plan: %s" % plan)
if [e["stage"] for e in ev if e["event"] == "stage"] != names:
    bad.append("stage events: %s" % [e["stage"] for e in ev if e["event"] == "stage"])
prog = [e for e in ev if e["event"] == "progress"]
steps = {"shape start": 40, "geometry": 10, "material start": 8, "appearance": 8, "export": 2}
for e in prog:
    if e["stage"] not in steps or e["stage_steps"] != steps[e["stage"]] or not 1 <= e["stage_done"] <= e["stage_steps"]:
        bad.append("progress line: %s" % e)
    if "loss" in e.get("status", ""):
        bad.append("a loss in the status at the default level: %s" % e)
    if not (e["eta_s"] == -1 or e["eta_s"] >= 0) or not 0 <= e["fraction"] <= 1:
        bad.append("eta_s or fraction: %s" % e)
for name in names:
    last = [e for e in prog if e["stage"] == name]
    if not last or last[-1]["stage_done"] != steps[name]:
        bad.append("%s: its last step not reported" % name)
if any(e["eta_s"] >= 0 for e in prog if e["stage"] == "shape start"):
    bad.append("an ETA during the shape start, before anything could predict the stages ahead")
end = [e for e in ev if e["event"] == "end"]
first = next((e for e in prog if e["eta_s"] >= 0), None)
if not end or first is None:
    bad.append("no end, or never an ETA")
else:
    real, left = end[0]["elapsed_s"], end[0]["elapsed_s"] - first["elapsed_s"]
    foretold = first["elapsed_s"] + first["eta_s"]
    print("first ETA %.1f s at %.1f s (%s step %d): the run foretold %.1f s, took %.1f s (ratio %.2f); "
          "%.1f s were left (ratio %.2f)" % (first["eta_s"], first["elapsed_s"], first["stage"], first["stage_done"],
                                             foretold, real, foretold / real, left, first["eta_s"] / left))
    if not 0.5 <= foretold / real <= 2:
        bad.append("the first ETA is off by more than a factor of 2")
for b in bad:
    print(b)
sys.exit(1 if bad else 0)
PY
finish
