#!/usr/bin/env bash
# matlaber serve --mpi N (docs/server.md): each job runs under mpirun as N processes sharing its
# steps. A job at tiny settings through the API ends with the asset that one process of `generate`
# makes with the same options, byte for byte (the pipeline's results do not depend on the number of
# processes); a running MPI job cancelled leaves none of its processes behind; --mpi is refused
# clearly where it cannot work. Skips (77) without libmicrohttpd, curl, mpirun, an MPI build or the model.
set -u
M=${1:?usage: cli_serve_mpi.sh path/to/matlaber}
. "$(dirname "$0")/lib_cli.sh"
HERE=$(cd "$(dirname "$0")" && pwd)
MODEL="$HERE/../models/matlaber-tiny"
command -v curl > /dev/null || { echo "skip: no curl (scripts/install-deps.sh)"; exit 77; }
command -v mpirun > /dev/null || { echo "skip: no mpirun (scripts/install-deps.sh installs OpenMPI)"; exit 77; }
[ -f "$MODEL/model_index.json" ] || { echo "skip: no $MODEL"; exit 77; }
"$M" serve --port 0 --runs "$T/probe" --help > /dev/null 2>&1
"$M" serve --host 0.0.0.0 --port 0 --runs "$T/probe" > "$T/out" 2> "$T/err"
grep -q "no HTTP server" "$T/err" && { echo "skip: a build without libmicrohttpd"; exit 77; }
# ASan's leak checker reports the MPI library's own allocations at a process's end (sanitizer build):
# the jobs' processes would exit 1 (the server's own leaks are cli_serve's to find)
export ASAN_OPTIONS="${ASAN_OPTIONS:-}:detect_leaks=0"
PIDS=()
cleanup() { for p in "${PIDS[@]}"; do kill -9 "$p" 2> /dev/null; done; rm -rf "$T"; }
trap cleanup EXIT

# --mpi where it cannot work: no mpirun on PATH (the refusal comes before the server starts)
expect 2 "--mpi 2 without mpirun on PATH" -- env PATH=/nonexistent "$M" serve --port 0 --mpi 2 --runs "$T/r0"
err_has "names what is missing" "no mpirun on PATH"
expect 2 "--mpi 0" -- "$M" serve --port 0 --mpi 0 --runs "$T/r0"
if ! "$M" serve --help | grep -q -- "--mpi"; then bad "--help lists --mpi"; else ok "--help lists --mpi"; fi

R="$T/runs"
"$M" serve --port 0 --runs "$R" --mpi 2 > "$T/s.out" 2> "$T/s.err" &
PID=$!
PIDS+=("$PID")
for _ in $(seq 100); do [ -s "$T/s.out" ] && break; sleep 0.1; done
U=$(head -1 "$T/s.out"); U=${U%/}
if grep -q "built without MPI" "$T/s.err"; then echo "skip: a build without MPI"; exit 77; fi
grep -q "each 2 processes" "$T/s.err" && ok "the start line says each job's processes" || { bad "start line"; cat "$T/s.err"; }

state() { curl -s --max-time 10 "$U/api/jobs/$1" | sed -n 's/.*"state":"\([a-z]*\)".*/\1/p'; }
wait_state() { for _ in $(seq 1500); do [ "$(state "$1")" = "$2" ] && return 0; sleep 0.2; done; return 1; }
post() { curl -s -o "$T/body" -w '%{http_code}' --max-time 20 -X POST -H 'Content-Type: application/json' --data-binary "$1" "$U/api/jobs"; }
id_of() { sed -n 's/.*"id":"\([^"]*\)".*/\1/p' "$T/body"; }
# a job's processes (mpirun and its ranks name the job's folder); on a loaded machine mpirun takes
# seconds to start its ranks, so wait up to a minute for a count (the loop ends as soon as it holds)
procs() { pgrep -f -- "$R/$1" | wc -l; }
wait_procs() { for _ in $(seq 300); do [ "$(procs "$1")" "$2" "$3" ] && return 0; sleep 0.2; done; return 1; }

# the job's options as generate's: 2 views a step; the server's --view-batch 1 gives each process one
OPTS='"init":"ellipsoid","material_start":0,"init_iters":10,"res":64,"grid":16,"views":2,"export_texture":64,"preview_every":0'
[ "$(post '{"prompt":"a gold goblet","seed":3,"geometry_iters":4,"appearance_iters":2,"checkpoint_every":2,'"$OPTS"'}')" = 201 ] \
  && ok "POST an MPI job: 201" || bad "POST: $(cat "$T/body")"
ID=$(id_of)
wait_state "$ID" done && ok "the MPI job is done" || { bad "the MPI job: $(state "$ID")"; cat "$R/.serve/$ID.log" 2> /dev/null | tail -5; }
curl -s --max-time 20 "$U/api/jobs/$ID/events" > "$T/events"
grep -q '"event":"progress"' "$T/events" && ok "its progress came through mpirun" || bad "no progress events"
[ "$(grep -c '"event":"result"' "$T/events")" = 1 ] && ok "one result event (rank 0 speaks)" || bad "result events: $(grep -c '"event":"result"' "$T/events")"
grep -q "some have none" "$R/.serve/$ID.log" && bad "a process had no views: $(grep 'some have none' "$R/.serve/$ID.log")" || ok "every process had views to guide"

# the same options, one process
export OMP_NUM_THREADS=1
expect 0 "the same job as one process" -- "$M" --threads 1 generate -p "a gold goblet" --seed 3 --geometry-iters 4 \
  --appearance-iters 2 --checkpoint-every 2 --init ellipsoid --set material_start=0 --init-iters 10 --res 64 \
  --grid 16 --views 2 --view-batch 1 --export-texture 64 --preview-every 0 -o "$T/one"
for f in mesh.obj material.safetensors asset.glb; do
  cmp -s "$R/$ID/final/$f" "$T/one/final/$f" && ok "$f: the one process's bytes" || bad "$f differs from the one process's"
done

# a running MPI job cancelled: none of its processes left
# (long in its shape initialisation, which no guidance can make collapse)
LONG=${OPTS/\"init_iters\":10/\"init_iters\":200000}
[ "$(post '{"prompt":"a gold goblet","seed":3,"geometry_iters":4,"appearance_iters":2,"checkpoint_every":1000,'"$LONG"'}')" = 201 ] \
  && ok "POST a long MPI job" || bad "POST long: $(cat "$T/body")"
LID=$(id_of)
wait_state "$LID" running && ok "it runs" || bad "long job: $(state "$LID")"
wait_procs "$LID" -ge 3
n0=$(procs "$LID")
[ "$n0" -ge 3 ] && ok "mpirun and its 2 processes run ($n0)" || bad "processes of the job: $n0"
code=$(curl -s -o /dev/null -w '%{http_code}' -X DELETE "$U/api/jobs/$LID")
[ "$code" = 200 ] && ok "DELETE the running MPI job" || bad "DELETE: $code"
wait_state "$LID" cancelled && ok "cancelled" || bad "state after DELETE: $(state "$LID")"
wait_procs "$LID" -eq 0
[ "$(procs "$LID")" = 0 ] && ok "none of its processes left" || { bad "left: $(pgrep -af -- "$R/$LID")"; }

# another, and the server killed with -9: the job's processes go with it (mpirun's parent-death
# signal, then OpenMPI ends its processes), so that a restarted server's resume is the run's only writer
[ "$(post '{"prompt":"a gold goblet","seed":3,"geometry_iters":4,"appearance_iters":2,"checkpoint_every":1000,'"$LONG"'}')" = 201 ] \
  && ok "POST another long MPI job" || bad "POST: $(cat "$T/body")"
KID=$(id_of)
wait_state "$KID" running && ok "it runs" || bad "job: $(state "$KID")"
wait_procs "$KID" -ge 3
kill -9 "$PID"; wait "$PID" 2> /dev/null
wait_procs "$KID" -eq 0
[ "$(procs "$KID")" = 0 ] && ok "kill -9 of the server: none of the job's processes left" \
  || bad "left after kill -9: $(pgrep -af -- "$R/$KID")"
finish
