#!/usr/bin/env bash
# Runs every libFuzzer target of a SOPE_FUZZ=ON build for a bounded time (`make fuzz`).
#
#   fuzz/run-fuzzers.sh FUZZ_BUILD [TARGET...]
#
# FUZZ_SECONDS  time per target (default 60)
# FUZZ_JOBS     targets run at once (default 1; each is single-threaded)
# SOPE          a `sope` program for the database seed (default build/app/sope)
#
# Seeds (fuzz/make-seeds.py) go to FUZZ_BUILD/fuzz/seeds/<target>, the growing corpus to
# FUZZ_BUILD/fuzz/corpus/<target>, crash/timeout/OOM inputs to
# FUZZ_BUILD/fuzz/artifacts/<target>/, the full output to FUZZ_BUILD/fuzz/logs/<target>.log.
# Prints one line per target (runs, coverage, exec/s) and exits non-zero when any target
# found a crash, a sanitizer report, a leak, a timeout (> 25 s an input) or > 2 GB RSS.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
build=${1:?usage: fuzz/run-fuzzers.sh FUZZ_BUILD [TARGET...]}
shift
seconds=${FUZZ_SECONDS:-60}
jobs=${FUZZ_JOBS:-1}
sope=${SOPE:-$here/../build/app/sope}
work=$build/fuzz
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  for program in "$work"/*_fuzz; do
    [ -x "$program" ] && targets+=("$(basename "$program")")
  done
fi
[ ${#targets[@]} -gt 0 ] || { echo "run-fuzzers: no *_fuzz programs in $work" >&2; exit 1; }

if [ ! -d "$work/seeds" ]; then
  seed_args=()
  [ -x "$sope" ] && seed_args=(--sope "$sope")
  "$here/make-seeds.py" "$work/seeds.tmp" "${seed_args[@]}"
  mv "$work/seeds.tmp" "$work/seeds"
fi

run_one() {
  local target=$1
  local corpus=$work/corpus/$target artifacts=$work/artifacts/$target/
  mkdir -p "$corpus" "$artifacts" "$work/logs" "$work/seeds/$target"
  local status=0
  "$work/$target" -max_total_time="$seconds" -timeout=25 -rss_limit_mb=2048 \
    -print_final_stats=1 -artifact_prefix="$artifacts" "$corpus" "$work/seeds/$target" \
    >"$work/logs/$target.log" 2>&1 || status=$?
  local last runs
  last=$(grep -E '^#[0-9]+' "$work/logs/$target.log" | tail -1 || true)
  runs=$(grep -oE 'stat::number_of_executed_units: *[0-9]+' "$work/logs/$target.log" |
         grep -oE '[0-9]+$' || echo "?")
  if [ "$status" -eq 0 ]; then
    echo "fuzz $target: ok, ${seconds}s, $runs runs; last: ${last:-none}"
  else
    echo "fuzz $target: FAILED (exit $status), see $work/logs/$target.log and $artifacts"
    grep -E '^(==[0-9]+==ERROR|SUMMARY|.*runtime error)' "$work/logs/$target.log" | head -5 || true
  fi
  echo "$status" >"$work/logs/$target.status"
}

for target in "${targets[@]}"; do
  [ -x "$work/$target" ] || { echo "run-fuzzers: $work/$target is not built" >&2; exit 1; }
  rm -f "$work/logs/$target.status"
  run_one "$target" &
  while [ "$(jobs -rp | wc -l)" -ge "$jobs" ]; do
    wait -n || true
  done
done
wait
failed=0
for target in "${targets[@]}"; do
  [ "$(cat "$work/logs/$target.status" 2>/dev/null || echo 1)" = 0 ] || failed=1
done
exit "$failed"
