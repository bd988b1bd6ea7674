#!/usr/bin/env bash
# The call side of the layers (docs/architecture.md "Layers"), read from the library's object files
# with nm: which file defines each global symbol and which files use it. Fails naming
#   - every group of files of src/ and of the program (tools/matlaber) that call each other in a
#     loop (a file-level strongly connected component of more than one file), and
#   - every function declared in a header of one folder (include/matlaber/X.h: its owner, as
#     check_layout.sh says; src/F/*.h: F) and defined in a folder above it.
# Only the C objects are read (matlaber_lib, mlb_f64): with the CUDA part built, src/nn/no_cuda.c is
# empty and the op list's CUDA functions come from src/cuda/, the one folder that by design defines
# what nn declares (its kernels implement the op tables), so both builds give the same graph.
# Sourced by check_layout.sh (tests/check_layout.sh ROOT BUILD_DIR), whose order and owner_of it uses.
check_calls() {
local build
build=$(cd "$1" && pwd)


local objs=() o d src syms decls h owners
for d in "$build"/CMakeFiles/matlaber_lib.dir/src "$build"/CMakeFiles/mlb_f64.dir/src "$build"/CMakeFiles/matlaber.dir/tools; do
  [ -d "$d" ] && while IFS= read -r o; do objs+=("$o"); done < <(find "$d" -name '*.c.o' | sort)
done
if [ ${#objs[@]} -eq 0 ]; then
  echo "check_calls: no object files under $build/CMakeFiles/matlaber_lib.dir: build the library first"
  return 1
fi

# "src/x/y.c SYMBOL TYPE" for each global symbol, defined (T D B R W V C) or used (U)
syms=$(for o in "${objs[@]}"; do
  src=${o#*.dir/}; src=${src%.o}
  [ -f "$src" ] || continue   # an object left from a file since moved or removed
  nm -P "$o" | awk -v f="$src" '$2 ~ /^[TDBRWVCU]$/ { print f, $1, $2 }'
done)

# "header symbol" for each function a header declares: a line at column 0 (not a directive, not
# static) whose first "name(" is the function's name
decls=$(find include/matlaber src -name '*.h' | sort | while IFS= read -r h; do
  sed 's://.*$::' "$h" | awk -v h="$h" '
    /^[A-Za-z_]/ && !/^(static|typedef|extern "C"|#)/ {
      if (match($0, /[A-Za-z_][A-Za-z_0-9]*[ \t]*\(/)) {
        name = substr($0, RSTART, RLENGTH); sub(/[ \t]*\($/, "", name); print h, name
      }
    }'
done)

owners=$(echo "$decls" | awk '{ print $1 }' | sort -u | while IFS= read -r h; do echo "$h $(owner_of "$h")"; done)

awk -v order="$order" -v owners="$owners" '
  BEGIN {
    n = split(order, o, " "); for (i = 1; i <= n; i++) rank[o[i]] = i
    m = split(owners, ol, "\n"); for (i = 1; i <= m; i++) { split(ol[i], p, " "); owner[p[1]] = p[2] }
    bad = 0
  }
  function folder(path,   p) { split(path, p, "/"); return p[2] }
  FNR == NR {   # symbols
    if ($3 == "U") use[++nu] = $1 SUBSEP $2
    else if (!($2 in def)) def[$2] = $1
    next
  }
  { decl[$2] = decl[$2] " " $1 }   # declarations
  END {
    # declared below, defined above
    for (s in decl) {
      if (!(s in def)) continue
      d = folder(def[s])
      nh = split(decl[s], hs, " ")
      for (i = 1; i <= nh; i++) {
        h = hs[i]; ho = owner[h]
        if (ho == "" || !(ho in rank) || !(d in rank)) continue
        if (rank[d] > rank[ho]) {
          printf "check_calls: %s declares %s (%s), defined in %s (%s), a folder above it\n", h, s, ho, def[s], d
          bad = 1
        }
      }
    }
    # the file-level graph
    for (i = 1; i <= nu; i++) {
      split(use[i], p, SUBSEP)
      if (!(p[2] in def)) continue
      a = p[1]; b = def[p[2]]
      if (a == b || ((a, b) in edge)) continue
      edge[a, b] = 1; out[a] = out[a] " " b; node[a] = 1; node[b] = 1
      via[a, b] = p[2]
    }
    # reach[a, b]: b reachable from a (a search from every file)
    for (a in node) {
      delete seen; nq = 0; q[++nq] = a; head = 1
      while (head <= nq) {
        x = q[head++]; nb = split(out[x], bs, " ")
        for (j = 1; j <= nb; j++) if (!(bs[j] in seen)) { seen[bs[j]] = 1; q[++nq] = bs[j]; reach[a, bs[j]] = 1 }
      }
    }
    # the loops: files that reach each other, each group once, its files sorted
    for (a in node) {
      if ((a in done) || !((a, a) in reach)) continue
      cnt = 0
      for (b in node) if (b == a || (((a, b) in reach) && ((b, a) in reach))) { grp[++cnt] = b; done[b] = 1 }
      for (i = 2; i <= cnt; i++) { t = grp[i]; for (j = i - 1; j >= 1 && grp[j] > t; j--) grp[j + 1] = grp[j]; grp[j + 1] = t }
      line = grp[1]; for (i = 2; i <= cnt; i++) line = line " " grp[i]
      printf "check_calls: these files call each other in a loop: %s\n", line
      for (i = 1; i <= cnt; i++) for (j = 1; j <= cnt; j++)
        if ((grp[i], grp[j]) in edge) printf "  %s -> %s (%s)\n", grp[i], grp[j], via[grp[i], grp[j]]
      bad = 1
    }
    exit bad
  }
' <(echo "$syms") <(echo "$decls") || return 1
echo "check_calls: no call loop among the files of src/ and tools/matlaber, and no function declared below its definition"
}
