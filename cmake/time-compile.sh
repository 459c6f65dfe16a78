#!/usr/bin/env bash
# Compiler/linker launcher that records how long each step takes (README "Build time"):
# configure with
#   -DCMAKE_CXX_COMPILER_LAUNCHER="$PWD/cmake/time-compile.sh"
#   -DCMAKE_CXX_LINKER_LAUNCHER="$PWD/cmake/time-compile.sh"
# (with ccache, compile through it: "$PWD/cmake/time-compile.sh;ccache") and set
# SOPE_COMPILE_TIMES=FILE for the build; each step appends
#   "cpu_seconds<TAB>wall_seconds<TAB>output" to FILE
# (CPU = user + system, which a loaded machine inflates less than the wall clock). Then
#   sort -rn FILE | head -30
set -u
output="?"
previous=""
for argument in "$@"; do
  [ "$previous" = "-o" ] && output=$argument
  previous=$argument
done
if [ -z "${SOPE_COMPILE_TIMES:-}" ] || [ ! -x /usr/bin/time ]; then
  exec "$@"
fi
record=$(mktemp)
status=0
/usr/bin/time -f '%U %S %e' -o "$record" "$@" || status=$?
tail -n 1 "$record" | awk -v o="$output" '{ printf "%.2f\t%.2f\t%s\n", $1 + $2, $3, o }' \
  >>"$SOPE_COMPILE_TIMES"
rm -f "$record"
exit $status
