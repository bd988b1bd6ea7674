#!/usr/bin/env bash
# matlaber serve (docs/server.md) through its API with curl: a job with the project's own model at
# tiny settings submitted, its events followed to the end, its .glb fetched and validated; a queued
# and a running job cancelled; a server killed with -9 mid-job and started again: the job resumes to
# the uninterrupted job's bytes and the finished ones are still listed. The hostile set: malformed
# JSON, wrong types, unknown keys, generate's own refusals, oversized bodies (Content-Length and
# chunked), long prompts, '..' / absolute / percent-encoded file routes, unknown ids, wrong methods,
# a full queue, too many connections, a half-sent request that times out without holding the
# server, and a non-loopback bind without, with a wrong and with the right token. The load (with
# tests/serve_load.py): 200 clients reading the list, jobs and events while two jobs run (--jobs 2)
# and 20 more are submitted: every answer 2xx, every event stream well-formed, no job lost or listed
# twice (while queued, once ended, after a restart), memory flat.
# Skips (77) in a build without libmicrohttpd, without curl or without the model.
set -u
M=${1:?usage: cli_serve.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
HERE=$(cd "$(dirname "$0")" && pwd)
MODEL="$HERE/../models/matlaber-tiny"
command -v curl > /dev/null || { echo "skip: no curl (scripts/install-deps.sh)"; exit 77; }
command -v python3 > /dev/null || { echo "skip: no python3 (the test reads JSON with it)"; exit 77; }
[ -f "$MODEL/model_index.json" ] || { echo "skip: no $MODEL"; exit 77; }
expect 0 "serve --help" -- "$M" serve --help
# a build without libmicrohttpd says so (exit 1) before it looks at the address
"$M" serve --host 0.0.0.0 --port 0 --runs "$T/probe" > "$T/out" 2> "$T/err"
if grep -q "no HTTP server" "$T/err"; then
  expect 1 "serve without libmicrohttpd: exit 1" -- "$M" serve --port 0 --runs "$T/probe"
  err_has "names what is missing" "libmicrohttpd"
  finish || exit 1; exit 77   # (the rest needs the server)
fi
export OMP_NUM_THREADS=1
# under the sanitizers (MLB_TEST_SANITIZED=1) the jobs run 5-10x slower: the page check waits longer
[ "${MLB_TEST_SANITIZED:-0}" = 1 ] && export MLB_SERVE_WAIT_MS=900000
PIDS=()
cleanup() { for p in "${PIDS[@]}"; do kill -9 "$p" 2> /dev/null; done; rm -rf "$T"; }
trap cleanup EXIT

# start_server NAME ARGS...: the server in the background; $PID, $U (its address, the first line)
start_server() {
  local name=$1; shift
  "$M" serve --port 0 "$@" > "$T/$name.out" 2> "$T/$name.err" &
  PID=$!
  PIDS+=("$PID")
  for _ in $(seq 100); do [ -s "$T/$name.out" ] && break; sleep 0.1; done
  U=$(head -1 "$T/$name.out")
}
# req NAME CODE curl-args...: the answer's status is CODE (body in $T/body)
req() { local name=$1 code=$2; shift 2
  local got; got=$(curl -s -o "$T/body" -w '%{http_code}' --max-time 20 "$@")
  if [ "$got" = "$code" ]; then ok "$name"; else bad "$name (HTTP $got, expected $code)"; head -c 400 "$T/body"; echo; fi; }
# body_has NAME TEXT: the last answer's body contains TEXT
body_has() { if grep -q -- "$2" "$T/body"; then ok "$1"; else bad "$1: body lacks '$2'"; head -c 400 "$T/body"; echo; fi; }
# the JSON error every refusal carries
json_error() { body_has "$1: a JSON error" '^{"error":"'; }
field() { python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))' "$T/body" "$1" 2> /dev/null; }
AUTH=()   # the token's header, once a server needs one
post() { curl -s -o "$T/body" -w '%{http_code}' --max-time 20 "${AUTH[@]}" -X POST -H 'Content-Type: application/json' --data-binary "$1" "$U/api/jobs"; }
# state ID: the job's state
state() { curl -s --max-time 10 "${AUTH[@]}" "$U/api/jobs/$1" | sed -n 's/.*"state":"\([a-z]*\)".*/\1/p'; }
wait_state() { for _ in $(seq 1500); do [ "$(state "$1")" = "$2" ] && return 0; sleep 0.2; done; return 1; }
wait_progress() {   # ID N: the job's events show at least N steps done
  for _ in $(seq 1500); do
    local d; d=$(curl -s --max-time 10 "${AUTH[@]}" "$U/api/jobs/$1" | sed -n 's/.*"done":\([0-9]*\).*/\1/p')
    [ -n "$d" ] && [ "$d" -ge "$2" ] && return 0; sleep 0.2; done; return 1; }

R="$T/runs"
TINY='"init":"ellipsoid","material_start":0,"init_iters":10,"res":64,"grid":16,"views":1,"export_texture":64,"preview_every":2'
SMALL='{"prompt":"a gold goblet","seed":3,"geometry_iters":4,"appearance_iters":2,"checkpoint_every":2,'"$TINY"'}'
LONG='{"prompt":"a red bowl","seed":5,"geometry_iters":3000,"appearance_iters":2,"checkpoint_every":1000,'"$TINY"'}'

# ---- start: loopback, the address first ----
echo "[${SECONDS} s] start"
expect 2 "--host 0.0.0.0 without --token" -- "$M" serve --host 0.0.0.0 --port 0 --runs "$R"
err_has "the refusal names --token" "give --token"
expect 2 "a short token" -- "$M" serve --host 0.0.0.0 --port 0 --token abc --runs "$R"
# (the default --timeout here: a browser under load may not read for 2 s, and a connection that
# reads nothing for --timeout seconds is closed too; the short timeout is the next server's)
start_server s1 --runs "$R" --max-body 2048 --max-prompt 64 --max-queue 2
[[ "$U" =~ ^http://127\.0\.0\.1:[0-9]+/$ ]] && ok "first line: the address ($U)" || bad "first line '$U'"
U=${U%/}
req "GET /api/jobs, none yet" 200 "$U/api/jobs"
body_has "an empty list" '"jobs":\[\]'

# ---- a job to its end ----
echo "[${SECONDS} s] a job to its end"
[ "$(post "$SMALL")" = 201 ] && ok "POST /api/jobs: 201" || bad "POST /api/jobs: $(cat "$T/body")"
ID=$(field 'd["id"]')
[ "$ID" = job-000001 ] && ok "the job's id" || bad "id '$ID'"
timeout 900 curl -sN --max-time 900 "$U/api/jobs/$ID/events" > "$T/events"
grep -q '^data: {"event":"progress"' "$T/events" && ok "events: the child's progress lines" || bad "events lack progress"
grep -q '^data: {"event":"result","command":"generate","finished":true' "$T/events" && ok "events: generate's result" || bad "events lack the result"
tail -2 "$T/events" | grep -q '"event":"job","id":"job-000001","state":"done","exit_code":0' \
  && ok "events end with the job done" || { bad "the last event"; tail -3 "$T/events"; }
grep '^data: ' "$T/events" | sed 's/^data: //' | python3 -c 'import json,sys; [json.loads(l) for l in sys.stdin]' \
  && ok "every event is one JSON object" || bad "an event is not JSON"
# a reconnecting EventSource (Last-Event-ID) gets only what followed
LAST=$(grep '^id: ' "$T/events" | tail -2 | head -1 | cut -c5-)
curl -sN --max-time 20 -H "Last-Event-ID: $LAST" "$U/api/jobs/$ID/events" > "$T/events2"
[ "$(grep -c '^data: ' "$T/events2")" = 1 ] && ok "Last-Event-ID: the rest only" || bad "Last-Event-ID: $(cat "$T/events2")"
req "GET /api/jobs/ID" 200 "$U/api/jobs/$ID"
body_has "done" '"state":"done"'
body_has "asset.glb listed" '"asset.glb"'
body_has "progress kept" '"progress":{"event":"end"'
req "GET the .glb" 200 "$U/api/jobs/$ID/files/asset.glb"
cp "$T/body" "$T/a.glb"
[ "$(head -c 4 "$T/a.glb")" = glTF ] && ok ".glb magic" || bad "not a .glb"
cmp -s "$T/a.glb" "$R/$ID/final/asset.glb" && ok "the run's own asset" || bad "the .glb differs from the run's"
if command -v node > /dev/null; then
  node "$HERE/gltf_validate.mjs" "$T/a.glb" > "$T/out" 2>&1; rc=$?
  if [ $rc = 0 ]; then ok "glTF-Validator: no errors"; elif [ $rc = 77 ]; then echo "(glTF-Validator not installed)"; else bad "glTF-Validator"; cat "$T/out"; fi
fi
curl -s -D "$T/headers" -o /dev/null "$U/api/jobs/$ID/files/asset.glb"
grep -qi '^content-type: model/gltf-binary' "$T/headers" && ok ".glb content type" || bad ".glb content type"
req "GET preview.png (the newest sheet)" 200 "$U/api/jobs/$ID/files/preview.png"
[ "$(head -c 4 "$T/body" | tail -c 3)" = PNG ] && ok "preview is a PNG" || bad "preview not a PNG"

# ---- the page: the app, and the viewer of `matlaber view` with the job's asset beside it ----
if [ -f "$HERE/../viewer/node_modules/three/package.json" ]; then
  req "GET / (the page)" 200 "$U/"
  body_has "the page follows events" "serve.js"
  req "GET /serve.js" 200 "$U/serve.js"
  body_has "with an EventSource" "new EventSource"
  req "the viewer of the job" 200 "$U/view/$ID/"
  body_has "the viewer's page" "viewer.js"
  req "the viewer's config" 200 "$U/view/$ID/viewer.json"
  body_has "names asset.glb" '"asset":[[:space:]]*"asset.glb"'
  req "the job's asset beside it" 200 "$U/view/$ID/asset.glb"
  cmp -s "$T/body" "$T/a.glb" && ok "the same .glb" || bad "/view/ID/asset.glb differs"
  # a latent-mode job (the default): the editor's codes and decoder beside it (docs/export.md)
  req "the viewer's config names the decoder" 200 "$U/view/$ID/viewer.json"
  body_has "decoder named" '"decoder":[[:space:]]*"asset.decoder.json"'
  req "the job's decoder" 200 "$U/view/$ID/asset.decoder.json"
  body_has "a decoder of the prior" '"format":"matlaber-latent-decoder-1"'
  req "the job's latent codes" 200 "$U/view/$ID/asset.latent.bin"
  [ "$(wc -c < "$T/body")" = $((64 * 64 * 16)) ] && ok "64² codes of 4 float32" || bad "latent.bin: $(wc -c < "$T/body") bytes"
  cmp -s "$T/body" "$R/$ID/final/asset.latent.bin" && ok "the run's own codes" || bad "/view/ID/asset.latent.bin differs"
  req "the viewer's script for them" 200 "$U/view/$ID/latent.js"
  req "three.js" 200 "$U/view/$ID/lib/three/build/three.module.js"
  req "an environment" 200 "$U/view/$ID/env/studio.hdr"
  for r in "/view/$ID/../../config.json" "/view/$ID/lib/../viewer.json" "/view/nope/" "/view/$ID/config.json" \
           "/view/$ID/loss.csv" "/view/$ID" "/view/../$ID/"; do
    code=$(curl -s --path-as-is -o "$T/body" -w '%{http_code}' "$U$r")
    case $code in 4??) ok "GET $r: $code" ;; *) bad "GET $r: $code" ;; esac
  done
  req "POST /" 405 -X POST "$U/"
  # the page in a browser: type, submit, watch, look, switch the light, download
  if command -v node > /dev/null; then
    node "$HERE/serve_check.mjs" "$U/" "{${TINY},\"geometry_iters\":4,\"appearance_iters\":2}" ${MLB_SERVE_SHOTS:-} > "$T/out" 2>&1; rc=$?
    cat "$T/out"
    if [ $rc = 0 ]; then ok "the page in headless Chromium"; elif [ $rc = 77 ]; then echo "($(tail -1 "$T/out"))"; else bad "the page in headless Chromium"; fi
  fi
else
  echo "(no viewer/node_modules: the page is not served; scripts/build.sh installs it)"
fi

# ---- latent edits saved as new jobs (POST /api/jobs/ID/edits) ----
echo "[${SECONDS} s] latent edits saved as new jobs"
edit() { curl -s -o "$T/body" -w '%{http_code}' --max-time 60 -X POST -H 'Content-Type: application/json' --data-binary "$2" "$U/api/jobs/$1/edits"; }
# codes A B: texels whose 4 codes differ, of all; "mean A B": B's every texel is A's mean code (to 1e-5)
codes() { python3 - "$@" << 'PY'
import sys, struct
a = struct.unpack('<%df' % (len(open(sys.argv[2], 'rb').read()) // 4), open(sys.argv[2], 'rb').read())
b = struct.unpack('<%df' % (len(open(sys.argv[3], 'rb').read()) // 4), open(sys.argv[3], 'rb').read())
n = len(a) // 4
if sys.argv[1] == 'diff':
    print(sum(1 for i in range(n) if a[4*i:4*i+4] != b[4*i:4*i+4]), n)
else:
    m = [sum(a[c::4]) / n for c in range(4)]
    print(max(abs(b[4*i+c] - m[c]) for i in range(n) for c in range(4)) < 1e-5)
PY
}
n_before=$(curl -s "$U/api/jobs" | grep -o '"edit_of"' | wc -l)
[ "$(edit "$ID" '{"offset":[0,0,0,0]}')" = 201 ] && ok "a zero edit of the whole asset: 201" || bad "zero edit: $(cat "$T/body")"
E0=$(field 'd["id"]')
body_has "done at once" '"state":"done"'
body_has "the edit's request kept" '"edit_of":"'"$ID"'"'
cmp -s "$R/$E0/final/asset.latent.bin" "$R/$ID/final/asset.latent.bin" && ok "a zero edit keeps the codes bitwise" || bad "zero edit changed the codes"
[ "$(edit "$ID" '{"offset":[0.5,0,-0.5,0]}')" = 201 ] && ok "an offset on the whole asset" || bad "whole edit: $(cat "$T/body")"
E1=$(field 'd["id"]')
[ "$(codes diff "$R/$ID/final/asset.latent.bin" "$R/$E1/final/asset.latent.bin")" = "4096 4096" ] && ok "every texel's code moved" \
  || bad "whole edit: $(codes diff "$R/$ID/final/asset.latent.bin" "$R/$E1/final/asset.latent.bin")"
req "the edit's job" 200 "$U/api/jobs/$E1"
for f in asset.glb asset.obj asset.mtl asset_kd.png asset_ks.png asset_roughness.png asset.latent.bin asset.decoder.json edit.json; do
  body_has "lists $f" "\"$f\""
done
req "its .glb" 200 "$U/api/jobs/$E1/files/asset.glb"
cp "$T/body" "$T/e.glb"
[ "$(head -c 4 "$T/e.glb")" = glTF ] && ok "a .glb" || bad "the edit's .glb"
if command -v node > /dev/null; then
  node "$HERE/gltf_validate.mjs" "$T/e.glb" > "$T/out" 2>&1; rc=$?
  if [ $rc = 0 ]; then ok "the edit's .glb: glTF-Validator, no errors"; elif [ $rc != 77 ]; then bad "the edit's .glb: glTF-Validator"; cat "$T/out"; fi
fi
cmp -s "$T/e.glb" "$T/a.glb" && bad "the edited .glb is the source's" || ok "its .glb differs from the source's"
req "listed in GET /api/jobs" 200 "$U/api/jobs"
body_has "the new job listed" "\"id\":\"$E1\",\"state\":\"done\""
grep -q '"state":[[:space:]]*"done"' "$R/.serve/$E1.json" && ok "its record (a restart lists it)" || bad "no record for $E1"
# a region: the material picked at a texel, within a radius of its code (a quarter of the codes'
# widest spread, as the page starts): some texels, not all
RAD=$(python3 -c 'import json,sys; l=json.load(open(sys.argv[1]))["latent"]; print(max(h - g for h, g in zip(l["max"], l["min"])) / 4)' "$R/$ID/final/asset.decoder.json")
[ "$(edit "$ID" '{"offset":[1,0,0,0],"region":{"texel":[20,20],"radius":'"$RAD"'}}')" = 201 ] && ok "an edit of a region (radius $RAD)" || bad "region edit: $(cat "$T/body")"
E2=$(field 'd["id"]')
read -r nd nt <<< "$(codes diff "$R/$ID/final/asset.latent.bin" "$R/$E2/final/asset.latent.bin")"
ne=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["texels_edited"])' "$R/$E2/final/edit.json")
[ "$nd" = "$ne" ] && [ "$nd" -gt 0 ] && [ "$nd" -lt "$nt" ] && ok "the region's $nd texels of $nt moved, the others kept" \
  || bad "region: $nd of $nt changed, edit.json says $ne"
# toward another asset's material, all the way (t 1, the whole asset): every code its mean
[ "$(edit "$ID" '{"offset":[0,0,0,0],"toward":{"job":"'"$E1"'","t":1}}')" = 201 ] && ok "toward another job's material" || bad "toward: $(cat "$T/body")"
E3=$(field 'd["id"]')
[ "$(codes mean "$R/$E1/final/asset.latent.bin" "$R/$E3/final/asset.latent.bin")" = True ] && ok "t 1: every code the other's mean" || bad "toward t 1"
# the hostile set of the route
for b in '{"offset":[0,0,0]}' '{"offset":[0,0,0,"a"]}' '{"offset":[1e9,0,0,0]}' '{"offset":[0,0,0,0],"x":1}' \
         '{"offset":[0,0,0,0],"offset":[0,0,0,0]}' '{"offset":[0,0,0,0],"region":{"texel":[64,0],"radius":1}}' \
         '{"offset":[0,0,0,0],"region":{"texel":[1.5,0],"radius":1}}' '{"offset":[0,0,0,0],"region":{"texel":[0,0],"radius":-1}}' \
         '{"offset":[0,0,0,0],"toward":{"job":"'"$ID"'","t":2}}' '{"offset":[0,0,0,0]} x' '[1,2]' '{"offset":'; do
  [ "$(edit "$ID" "$b")" = 400 ] && ok "400: $b" || bad "not 400: $b: $(cat "$T/body")"
  json_error "$b"
done
[ "$(edit nope '{"offset":[0,0,0,0]}')" = 404 ] && ok "an unknown job: 404" || bad "unknown job"
[ "$(edit "$ID" '{"offset":[0,0,0,0],"toward":{"job":"nope","t":0.5}}')" = 404 ] && ok "toward an unknown job: 404" || bad "toward unknown"
req "GET .../edits: 405" 405 "$U/api/jobs/$ID/edits"
req "an edit not sent as JSON: 415" 415 -X POST --data-binary '{"offset":[0,0,0,0]}' "$U/api/jobs/$ID/edits"
head -c 5000 /dev/zero | tr '\0' ' ' > "$T/big"
req "an edit over 4096 bytes: 413" 413 -X POST -H 'Content-Type: application/json' --data-binary @"$T/big" "$U/api/jobs/$ID/edits"
n_edits=$(curl -s "$U/api/jobs" | grep -o '"edit_of"' | wc -l)
[ "$n_edits" = $((n_before + 4)) ] && ok "a refused edit makes no job (4 more edits listed)" || bad "$n_edits edits listed, $n_before before"
kill -0 "$PID" && ok "the server took them all" || bad "the server died"

# ---- the hostile set ----
echo "[${SECONDS} s] the hostile set"
for b in '{"prompt":' 'not json' '{"prompt":"a gold goblet"} x' '' '[1]' '"a gold goblet"' '{"prompt":"a","prompt":"b"}'; do
  [ "$(post "$b")" = 400 ] && ok "400 for body '$b'" || bad "body '$b': $(cat "$T/body")"
done
json_error "malformed JSON"
for b in '{"prompt":5}' '{"prompt":"a gold goblet","seed":"1"}' '{"prompt":"a gold goblet","seed":-1}' \
         '{"prompt":"a gold goblet","seed":1.5}' '{"prompt":"a gold goblet","res":true}' '{"prompt":null}' \
         '{"prompt":"a gold goblet","views":[4]}' '{"prompt":"a gold goblet","out":"/tmp/x"}' '{"seed":1}' \
         '{"prompt":"a gold\u0000goblet"}' '{"prompt":"a gold goblet\n--seed 3"}' '{"prompt":"a gold goblet","init":"/etc/passwd"}' \
         '{"prompt":"a gold goblet","preset":"../x"}'; do
  [ "$(post "$b")" = 400 ] && ok "400 for $b" || bad "$b: $(cat "$T/body")"
done
json_error "wrong types"
[ "$(post '{"prompt":"a gold goblet","res":7}')" = 400 ] && ok "generate's own check: res 7" || bad "res 7 accepted"
body_has "generate's message" "multiple of 8"
[ "$(post '{"prompt":"a purple giraffe"}')" = 400 ] && ok "generate's own check: words the model never saw" || bad "unknown words accepted"
[ "$(post '{"prompt":"a gold goblet","preset":"fast"}')" = 400 ] && ok "an unknown preset" || bad "preset fast accepted"
body_has "names the presets" "tiny"
P65=$(printf 'a%.0s' $(seq 65))
[ "$(post "{\"prompt\":\"$P65\"}")" = 400 ] && ok "a prompt over --max-prompt" || bad "long prompt accepted"
head -c 3000 /dev/zero | tr '\0' ' ' > "$T/big.json"
req "a body over --max-body (Content-Length)" 413 -X POST --data-binary @"$T/big.json" "$U/api/jobs"
json_error "oversized body"
req "a body over --max-body (chunked)" 413 -X POST -H 'Content-Type: application/json' -H 'Transfer-Encoding: chunked' \
  --data-binary @"$T/big.json" "$U/api/jobs"
# what a page of another site can send without asking first (a form, text/plain), and DNS rebinding
req "a form's POST (not JSON): 415" 415 -X POST --data-binary "$SMALL" "$U/api/jobs"
req "text/plain: 415" 415 -X POST -H 'Content-Type: text/plain' --data-binary "$SMALL" "$U/api/jobs"
req "a Host that is not this machine: 403" 403 -H 'Host: evil.example:80' "$U/api/jobs"
json_error "foreign Host"
req "Host: localhost" 200 -H "Host: localhost:${U##*:}" "$U/api/jobs"
for p in "../config.json" "..%2fconfig.json" "%2e%2e%2fconfig.json" "%2fetc%2fpasswd" "/etc/passwd" "final/asset.glb" \
         "asset.glb%00" "checkpoints" "../../../../etc/passwd" "." ".." "config.json/" "Asset.glb"; do
  code=$(curl -s --path-as-is -o "$T/body" -w '%{http_code}' "$U/api/jobs/$ID/files/$p")
  case $code in 4??) if grep -q glTF "$T/body"; then bad "files/$p: served a file"; else ok "files/$p: $code"; fi ;;
                 *) bad "files/$p: HTTP $code" ;; esac
done
code=$(curl -s --path-as-is -o "$T/body" -w '%{http_code}' "$U/api/jobs/../jobs/$ID")
case $code in 4??) ok "'..' in the route: $code" ;; *) bad "'..' in the route: $code" ;; esac
req "config.json: a listed file" 200 "$U/api/jobs/$ID/files/config.json"
for r in "/api/jobs/job-999999" "/api/jobs/nope/events" "/api/jobs/nope/files/asset.glb" "/api/jobs/%2e%2e" "/nothing" \
         "/api/jobs/$ID/other"; do
  code=$(curl -s -o "$T/body" -w '%{http_code}' --path-as-is "$U$r")
  case $code in 40[04]) ok "GET $r: $code" ;; *) bad "GET $r: $code" ;; esac
done
req "DELETE an unknown id" 404 -X DELETE "$U/api/jobs/job-999999"
req "DELETE a finished job" 409 -X DELETE "$U/api/jobs/$ID"
req "PUT /api/jobs" 405 -X PUT "$U/api/jobs"
json_error "wrong method"
curl -s -D "$T/headers" -o /dev/null -X PUT "$U/api/jobs"
grep -qi '^allow: GET, HEAD, POST' "$T/headers" && ok "405 names the route's methods" || bad "Allow header"
req "DELETE /api/jobs" 405 -X DELETE "$U/api/jobs"
req "POST /api/jobs/ID" 405 -X POST -d '{}' "$U/api/jobs/$ID"
req "POST .../events" 405 -X POST "$U/api/jobs/$ID/events"
req "DELETE .../files/asset.glb" 405 -X DELETE "$U/api/jobs/$ID/files/asset.glb"

# ---- cancel: a running and a queued job; the queue's limit ----
echo "[${SECONDS} s] cancel"
[ "$(post "$LONG")" = 201 ] && ok "submit a long job" || bad "long job: $(cat "$T/body")"
L1=$(field 'd["id"]')
[ "$(post "$LONG")" = 201 ] && ok "a second one queues" || bad "second long job"
L2=$(field 'd["id"]')
[ "$(post "$LONG")" = 201 ] && ok "a third" || bad "third long job"
L3=$(field 'd["id"]')
wait_state "$L1" running && ok "the first runs" || bad "the first never ran"
[ "$(post "$LONG")" = 429 ] && ok "a full queue (--max-queue 2): 429" || bad "no 429 for a full queue: $(cat "$T/body")"
[ "$(state "$L2")" = queued ] && ok "one job at a time: the second waits" || bad "second: $(state "$L2")"
req "DELETE a queued job" 200 -X DELETE "$U/api/jobs/$L3"
[ "$(state "$L3")" = cancelled ] && ok "the queued job is cancelled" || bad "L3: $(state "$L3")"
[ -f "$HERE/../viewer/node_modules/three/package.json" ] && req "a job without codes: no editor (204)" 204 "$U/view/$L3/asset.decoder.json"
wait_progress "$L1" 2 || bad "the long job shows no progress"
req "DELETE a running job" 200 -X DELETE "$U/api/jobs/$L1"
wait_state "$L1" cancelled && ok "the running job is cancelled" || bad "L1: $(state "$L1")"
timeout 20 curl -sN --max-time 20 "$U/api/jobs/$L1/events" | tail -2 | grep -q '"state":"cancelled"' \
  && ok "its events end with cancelled" || bad "cancel event"
wait_state "$L2" running && ok "the next job starts" || bad "L2: $(state "$L2")"
req "DELETE it too" 200 -X DELETE "$U/api/jobs/$L2"
wait_state "$L2" cancelled || bad "L2 not cancelled"
kill -0 "$PID" && ok "the server outlived its jobs" || bad "the server died"

# ---- kill -9 mid-job, start again: the job resumes to the uninterrupted job's asset ----
echo "[${SECONDS} s] kill -9 mid-job, start again"
RESUME='{"prompt":"a gold goblet","seed":3,"geometry_iters":16,"appearance_iters":2,"checkpoint_every":2,'"$TINY"'}'
[ "$(post "$RESUME")" = 201 ] && ok "submit the job to interrupt" || bad "resume job"
K=$(field 'd["id"]')
[ "$(post "$SMALL")" = 201 ] && ok "and one queued behind it" || bad "queued job"
Q=$(field 'd["id"]')
wait_progress "$K" 4 && ok "it got past a checkpoint" || bad "no progress"
kill -9 "$PID"; wait "$PID" 2> /dev/null
sleep 0.5
# the job went with the server (its parent-death signal): no second writer when it resumes
pgrep -f -- "-o $R/$K\$" > /dev/null && bad "the job outlived the server" || ok "the job died with the server"
# an edit the server was writing when it died (RUNS/job-N.part) is removed at the start; others' folders stay
mkdir -p "$R/job-999999.part/final" "$R/mine.part" && echo x > "$R/job-999999.part/final/asset.glb"
start_server s2 --runs "$R" --timeout 2 --max-connections 6
U=${U%/}
[ ! -e "$R/job-999999.part" ] && ok "a half-written edit removed at the start" || bad "job-999999.part left"
[ -d "$R/mine.part" ] && ok "a folder of someone else's named .part kept" || bad "mine.part removed"
# a half-sent request: closed after --timeout (2 s), and the server answers others meanwhile
PORT=${U##*:}
t0=$(date +%s%N)
exec 3<> "/dev/tcp/127.0.0.1/$PORT"
printf 'POST /api/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{"prompt":' >&3
req "answers while a request hangs" 200 "$U/api/jobs"
timeout 15 cat <&3 > "$T/half"
exec 3<&-
ms=$((($(date +%s%N) - t0) / 1000000))
if [ "$ms" -ge 1500 ] && [ "$ms" -lt 8000 ]; then ok "half-sent request closed after $ms ms"; else bad "half-sent request: $ms ms"; fi
grep -q '^HTTP/1.1 201' "$T/half" && bad "the half request made a job" || ok "the half request made no job"
# too many connections: 6 allowed, 6 idle ones open, the 7th gets a 429
for fd in 3 4 5 6 7 8; do eval "exec $fd<> /dev/tcp/127.0.0.1/$PORT"; done
req "a connection over --max-connections" 429 "$U/api/jobs"
json_error "too many connections"
for fd in 3 4 5 6 7 8; do eval "exec $fd<&-"; done
sleep 0.3
req "the server after the idle connections" 200 "$U/api/jobs"

wait_state "$K" done && ok "after the restart the job resumed and finished" || { bad "K: $(state "$K")"; cat "$R/.serve/$K.log" | tail -5; }
grep -q -- "--resume\|resum" "$R/.serve/$K.log" && ok "its log shows a resume" || echo "(note: no resume line in the log)"
req "GET /api/jobs after the restart" 200 "$U/api/jobs"
for j in "$ID" "$L1" "$L2" "$L3" "$K" "$Q"; do body_has "$j still listed" "\"id\":\"$j\""; done
wait_state "$Q" done && ok "the job queued before the kill ran after the restart" || bad "Q: $(state "$Q")"
cmp -s "$R/$Q/final/asset.glb" "$R/$ID/final/asset.glb" && ok "its asset: bitwise the first job's (the same request)" \
  || bad "the queued job's asset differs from the same request's"
[ "$(post "$RESUME")" = 201 ] && ok "the same job, uninterrupted" || bad "reference job"
K2=$(field 'd["id"]')
wait_state "$K2" done || bad "reference job: $(state "$K2")"
cmp -s "$R/$K/final/asset.glb" "$R/$K2/final/asset.glb" && ok "resumed asset: bitwise the uninterrupted one" \
  || bad "the resumed job's asset differs from the uninterrupted one"

# ---- a mesh uploaded to paint (base64 in the JSON), and paint's own checks on it ----
echo "[${SECONDS} s] paint an uploaded mesh"
printf 'v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n' > "$T/cube.obj"
printf 'f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n' >> "$T/cube.obj"
printf 'v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\nf 1 1 2\n' > "$T/flat.obj"
CUBE=$(base64 -w0 "$T/cube.obj")
PAINT='"res":32,"views":2,"appearance_iters":4,"checkpoint_every":2,"preview_every":2,"export_texture":64,"material_start":0'
[ "$(post '{"prompt":"a red bowl","mesh":{"format":"obj","data":"'"$CUBE"'"},'"$PAINT"'}')" = 201 ] && ok "POST a mesh: 201" \
  || bad "POST a mesh: $(cat "$T/body")"
P=$(field 'd["id"]')
body_has "the record keeps the mesh's format and size, not its bytes" '"mesh":{"format":"obj","bytes":'"$(stat -c %s "$T/cube.obj")"'}'
wait_state "$P" done && ok "the paint job finished" || { bad "paint job: $(state "$P")"; tail -5 "$R/.serve/$P.log"; }
grep -q '"paint_mesh"' "$R/$P/config.json" && ok "it is a paint run" || bad "not a paint run"
req "its .glb" 200 "$U/api/jobs/$P/files/asset.glb"
[ "$(head -c 4 "$T/body")" = glTF ] && ok "a .glb" || bad "no .glb"
[ "$(post '{"prompt":"a red bowl","mesh":{"format":"obj","data":"'"$(base64 -w0 "$T/flat.obj")"'"}}')" = 400 ] \
  && ok "a mesh paint refuses: 400" || bad "flat mesh: $(cat "$T/body")"
body_has "paint's own message" "zero area"
grep -q "uploads" "$T/body" && bad "the message shows the server's upload path" || ok "the message says 'the mesh', not a path"
[ "$(post '{"prompt":"a red bowl","mesh":{"format":"glb","data":"Z2xURg=="}}')" = 400 ] && ok "a truncated .glb: 400" || bad "glb"
for m in '{"format":"gltf","data":"'"$CUBE"'"}' '{"format":"obj","data":"not base64!"}' '{"format":"obj","data":"QQ="}' \
         '{"format":"obj"}' '{"format":"obj","data":"'"$CUBE"'","path":"/etc/passwd"}' '"'"$CUBE"'"'; do
  [ "$(post '{"prompt":"a red bowl","mesh":'"$m"'}')" = 400 ] && ok "mesh ${m:0:40}...: 400" || bad "mesh $m: $(cat "$T/body")"
done
[ "$(post '{"prompt":"a red bowl","grid":16,"mesh":{"format":"obj","data":"'"$CUBE"'"}}')" = 400 ] \
  && ok "a geometry option with a mesh: 400" || bad "grid with a mesh"
body_has "paint's reason" "no geometry stage"
[ -z "$(ls "$R/.serve/uploads" | grep -v '^job-')" ] && ok "refused uploads leave nothing" || bad "uploads left: $(ls "$R/.serve/uploads")"
# a paint job killed with the server mid-way resumes to the uninterrupted paint job's bytes
PRES='{"prompt":"a red bowl","mesh":{"format":"obj","data":"'"$CUBE"'"},"res":32,"views":2,"appearance_iters":24,"checkpoint_every":2,"preview_every":2,"export_texture":64,"material_start":0}'
[ "$(post "$PRES")" = 201 ] && ok "a paint job to interrupt" || bad "paint resume job: $(cat "$T/body")"
PK=$(field 'd["id"]')
wait_progress "$PK" 4 && ok "it got past a checkpoint" || bad "paint job: no progress"
kill -9 "$PID"; wait "$PID" 2> /dev/null
sleep 0.5
start_server s2b --runs "$R"
U=${U%/}
wait_state "$PK" done && ok "after the restart the paint job resumed and finished" || { bad "PK: $(state "$PK")"; tail -5 "$R/.serve/$PK.log"; }
[ "$(post "$PRES")" = 201 ] && ok "the same paint job, uninterrupted" || bad "paint reference: $(cat "$T/body")"
PK2=$(field 'd["id"]')
wait_state "$PK2" done || bad "paint reference: $(state "$PK2")"
cmp -s "$R/$PK/final/asset.glb" "$R/$PK2/final/asset.glb" && ok "resumed paint asset: bitwise the uninterrupted one" \
  || bad "the resumed paint job's asset differs from the uninterrupted one"
kill "$PID"; wait "$PID" 2> /dev/null
[ $? = 0 ] && ok "Ctrl-C/SIGTERM: a clean exit" || bad "exit status on SIGTERM"

# ---- a non-loopback bind needs the token ----
echo "[${SECONDS} s] a non-loopback bind needs the token"
TOK=0123456789abcdef0123
start_server s3 --host 0.0.0.0 --token "$TOK" --runs "$R" --timeout 2 --jobs 2 --max-connections 400 --max-queue 20
U="http://127.0.0.1:${U##*:}"; U=${U%/}
req "no token: 401" 401 "$U/api/jobs"
json_error "missing token"
req "a wrong token: 401" 401 -H "Authorization: Bearer 0123456789abcdef0124" "$U/api/jobs"
req "a token's prefix: 401" 401 -H "Authorization: Bearer 0123456789abcdef012" "$U/api/jobs"
req "the token in another scheme: 401" 401 -H "Authorization: Basic $TOK" "$U/api/jobs"
req "POST without the token: 401" 401 -X POST --data-binary "$SMALL" "$U/api/jobs"
req "the right token" 200 -H "Authorization: Bearer $TOK" "$U/api/jobs"
req "the token as ?token= (EventSource, links)" 200 "$U/api/jobs/$ID/files/asset.glb?token=$TOK"
req "the token as the page's cookie" 200 -b "matlaber_token=$TOK" "$U/api/jobs/$ID"
req "a wrong cookie" 401 -b "matlaber_token=x$TOK" "$U/api/jobs/$ID"
req "a foreign Host is fine with a token" 200 -H 'Host: my-server.example' -H "Authorization: Bearer $TOK" "$U/api/jobs"

# ---- load: 200 clients reading while two jobs run (--jobs 2) and 20 more are submitted ----
# (tests/serve_load.py: each request on a connection of its own; limits above 200 clients: a closed
# connection counts until its thread has seen the close, and 20 jobs wait)
echo "[${SECONDS} s] load"
AUTH=(-H "Authorization: Bearer $TOK")
# two jobs that run for minutes, an event a step (4 geometry steps, then appearance ones: LONG's
# geometry may end in "no surface" after a few seconds); cancelled at the end
BUSY='{"prompt":"a gold goblet","seed":5,"geometry_iters":4,"appearance_iters":5000,"checkpoint_every":1000,'"$TINY"'}'
[ "$(post "$BUSY")" = 201 ] && B1=$(field 'd["id"]') || bad "busy job: $(cat "$T/body")"
[ "$(post "$BUSY")" = 201 ] && B2=$(field 'd["id"]') || bad "busy job: $(cat "$T/body")"
wait_progress "$B1" 1 && wait_progress "$B2" 1 && ok "--jobs 2: two jobs run at once" \
  || bad "--jobs 2: $B1 $(state "$B1"), $B2 $(state "$B2")"
echo "$SMALL" > "$T/small.json"
rss() { awk '/^VmRSS/ {print $2}' "/proc/$PID/status"; }
load_round() {   # N ARGS...: 200 clients, 5 requests each, then a second for the last closes to land
  python3 "$HERE/serve_load.py" "$U" --token "$TOK" --clients 200 --requests 5 --finished "$ID" --running "$B1,$B2" \
    "${@:2}" > "$T/load" 2>&1 && ok "load round $1: $(head -1 "$T/load")" || { bad "load round $1"; cat "$T/load"; }
  sleep 1
}
# (the allocator's arenas and the threads' stacks grow over the first rounds, to settle by the third)
load_round 1 --submit "$T/small.json" --count 20 --ids "$T/ids"
load_round 2; load_round 3
r1=$(rss)
load_round 4; load_round 5; load_round 6
r2=$(rss)
if [ "${MLB_TEST_SANITIZED:-0}" = 1 ]; then   # ASan keeps freed memory in quarantine: RSS says nothing there
  echo "(sanitized: RSS $r1 -> $r2 kB, not judged; the leak check at the server's exit is)"
else
  [ $((r2 - r1)) -lt 8192 ] && ok "memory flat over 3 more rounds (RSS $r1 -> $r2 kB)" || bad "RSS grew $r1 -> $r2 kB"
fi
# no job lost or listed twice, while they wait and once they ended (18 cancelled while queued, the
# busy two cancelled, then the first two of the 20 run to their end)
S20=$(sort -u "$T/ids")
[ "$(echo "$S20" | grep -c '^job-')" = 20 ] && ok "20 jobs submitted under the load, 20 ids" || bad "ids: $(cat "$T/ids")"
[ "$(post "$SMALL")" = 429 ] && ok "the queue's limit still holds (--max-queue 20): 429" || bad "a 21st queued job: $(cat "$T/body")"
# list_has WHAT STATE...: B1, B2 and the 20 (in id order) each listed exactly once, in these states
list_has() { local what=$1; shift
  curl -s --max-time 20 "${AUTH[@]}" "$U/api/jobs" > "$T/list"
  python3 -c '
import json, sys
jobs = json.load(open(sys.argv[1]))["jobs"]
want = dict(zip(sys.argv[3:], sys.argv[2].split()))
ids = [j["id"] for j in jobs]
bad = [f"{i} listed {ids.count(i)} times" for i in want if ids.count(i) != 1]
for j in jobs:
    if want.get(j["id"], j["state"]) != j["state"]:
        bad.append(j["id"] + " " + j["state"] + ", not " + want[j["id"]])
bad += [f"{len(want)} jobs to look for, not 22"] if len(want) != 22 else []
print("\n".join(bad))
sys.exit(1 if bad else 0)' "$T/list" "$*" "$B1" "$B2" $S20 > "$T/out" && ok "$what" || { bad "$what"; cat "$T/out"; }
}
list_has "each of the 22 jobs listed once: two running, 20 queued" running running $(printf 'queued %.0s' $(seq 20))
n=0; for j in $(echo "$S20" | tail -18); do [ "$(curl -s -o /dev/null -w '%{http_code}' "${AUTH[@]}" -X DELETE "$U/api/jobs/$j")" = 200 ] && n=$((n + 1)); done
[ "$n" = 18 ] && ok "18 queued jobs cancelled" || bad "$n of 18 queued jobs cancelled"
for j in "$B1" "$B2"; do req "DELETE the busy $j" 200 "${AUTH[@]}" -X DELETE "$U/api/jobs/$j"; done
for j in $(echo "$S20" | head -2); do wait_state "$j" done && ok "$j, queued under the load, ran to its end" || bad "$j: $(state "$j")"; done
ENDED="cancelled cancelled done done $(printf 'cancelled %.0s' $(seq 18))"
list_has "once they ended: each listed once, none lost" $ENDED
n=0; for j in "$B1" "$B2" $S20; do   # each job's events: the child's, then the server's closing event once
  curl -sN --max-time 20 "${AUTH[@]}" "$U/api/jobs/$j/events" > "$T/ev"
  [ "$(grep -c '^data: {"event":"job"' "$T/ev")" = 1 ] && tail -2 "$T/ev" | grep -q "^data: {\"event\":\"job\",\"id\":\"$j\"" && n=$((n + 1))
done
[ "$n" = 22 ] && ok "the 22 jobs' events each end with their own job event" || bad "$((22 - n)) jobs' events do not end with their job event"
kill "$PID"; wait "$PID" 2> /dev/null
[ $? = 0 ] && ok "a clean exit after the load (under ASan: no leak)" || bad "exit status after the load"
start_server s4 --runs "$R"
U=${U%/}; AUTH=()
list_has "after a restart the 22 are listed as they ended" $ENDED
kill "$PID"; wait "$PID" 2> /dev/null
echo "[${SECONDS} s] end"
finish
