# Shared by the tests/cli_*.sh scripts (not itself a test) (sourced): a scratch folder $T, pass/fail counting, and
# checks of a command's exit status, stderr and PNG output size.
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
pass=0; fail=0
ok() { pass=$((pass+1)); echo "ok   $1"; }
bad() { fail=$((fail+1)); echo "FAIL $1"; }
# expect CODE NAME -- command...: the command exits with CODE (stdout in $T/out, stderr in $T/err)
# (a command of 5 s or more says how long it took: where a slow CI run spends its time)
expect() { local code=$1 name=$2 t0=$SECONDS; shift 3; "$@" > "$T/out" 2> "$T/err"; local rc=$?
  [ $((SECONDS - t0)) -ge 5 ] && name="$name [$((SECONDS - t0)) s]"
  if [ "$rc" = "$code" ]; then ok "$name"; else bad "$name (exit $rc, expected $code)"; cat "$T/err"; fi; }
# err_has NAME TEXT: the last command's stderr contains TEXT
err_has() { if grep -q -- "$2" "$T/err"; then ok "$1"; else bad "$1: stderr lacks '$2'"; cat "$T/err"; fi; }
# width x height of a PNG, from its IHDR chunk
png_size() { od -An -tu1 -j16 -N8 "$1" | awk '{print ($1*16777216+$2*65536+$3*256+$4) "x" ($5*16777216+$6*65536+$7*256+$8)}'; }
# the closing line CTest's runner and the CI read; exit status 1 when anything failed
finish() { echo "$pass passed, $fail failed"; [ "$fail" = 0 ]; }
