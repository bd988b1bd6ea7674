#!/usr/bin/env bash
# Several processes on one asset (docs/benchmarks.md, "Several processes"): the tiny preset's steps
# per second with each step's 4 views split over 2 MPI processes of 1 thread each, against 1 process
# of 1 thread, and what the collectives cost. Both runs must end in the same bytes (checked).
# VIEW_BATCH: views per guidance call (--view-batch; the batches go whole to the processes): 1, as
# docs/benchmarks.md measured it (one view per call was then the only way), or 2 (a call of 2 views
# on each process).
# Usage: bench/mpi_scaling.sh [BUILD_DIR] [REPEATS] [GEOMETRY_STEPS] [APPEARANCE_STEPS] [VIEW_BATCH]
set -u
B=${1:-build}; R=${2:-2}; G=${3:-12}; A=${4:-6}; K=${5:-1}
M="$B/matlaber"
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
args="generate -p \"a gold goblet\" --preset tiny --hash-table-log2 16 --init-iters 20 --geometry-iters $G \
--appearance-iters $A --view-batch $K --export-texture 0 --preview-every 0 --checkpoint-every 100000"
echo "cpu: $(grep -m1 '^model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //'), $(nproc --all) vCPUs; load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "command: [mpirun -n 2] $M --threads 1 $args -o DIR"
for r in $(seq 1 "$R"); do
  for n in 1 2; do
    out="$T/run_${n}_$r"
    if [ "$n" = 1 ]; then launch=""; else launch="mpirun --oversubscribe --allow-run-as-root --bind-to core -n $n"; fi
    eval "$launch $M --threads 1 $args -o $out" 2> "$T/log" > /dev/null || { cat "$T/log"; exit 1; }
    grep -E "^(geometry|appearance) stage:" "$T/log" | sed "s/^/repeat $r, $n process(es): /"
  done
  cmp -s "$T/run_1_$r/final/material.safetensors" "$T/run_2_$r/final/material.safetensors" &&
    cmp -s "$T/run_1_$r/final/mesh.obj" "$T/run_2_$r/final/mesh.obj" && echo "repeat $r: 1 and 2 processes, same bytes" ||
    echo "repeat $r: 1 and 2 processes DIFFER"
done
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
