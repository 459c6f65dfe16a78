#!/usr/bin/env bash
# Runs every benchmark program (heavy; not part of the tests or CI). Each prints its
# comparison with a peer run in the same process and a summary of the ratios.
#
#   scripts/run-benchmarks.sh [BUILD] [BENCHMARK_ARGS...]
#       e.g. scripts/run-benchmarks.sh build --benchmark_format=json: then each program's
#       stdout is its JSON report alone (logs and summaries go to stderr, bench_support.h)
#   scripts/run-benchmarks.sh --check-json PROGRAM FILTER
#       runs PROGRAM's benchmarks matching FILTER once with --benchmark_format=json and
#       checks that stdout parses as JSON with at least one benchmark (a ctest runs this).
set -euo pipefail
if [ "${1:-}" = "--check-json" ]; then
  program=${2:?usage: run-benchmarks.sh --check-json PROGRAM FILTER}
  filter=${3:?usage: run-benchmarks.sh --check-json PROGRAM FILTER}
  out=$(mktemp)
  trap 'rm -f "$out"' EXIT
  "$program" --benchmark_format=json --benchmark_filter="$filter" \
    --benchmark_min_time=0.001 --benchmark_repetitions=1 >"$out"
  python3 - "$out" "$program" <<'PY'
import json, sys
path, program = sys.argv[1], sys.argv[2]
try:
    report = json.load(open(path))
except ValueError as e:
    text = open(path).read()
    sys.exit(f"{program}: stdout is not JSON ({e}); it begins: {text[:200]!r}")
runs = report.get("benchmarks", [])
if not runs:
    sys.exit(f"{program}: the JSON report holds no benchmark")
print(f"{program}: JSON report with {len(runs)} benchmark(s): "
      + ", ".join(r["name"] for r in runs))
PY
  exit 0
fi
# recognise_bench builds its ~12k-view database once (2–4 min) and caches it in
# $SOPE_BENCH_CACHE (default /tmp/sope-bench-cache); SOPE_BENCH_PASSES sets its passes over
# the queries (default 2). Pin to one core for the issue-4 numbers: taskset -c 1.
build=${1:-build}
shift || true
for bench in "$build"/bench/*_bench; do
  [ -x "$bench" ] || continue
  echo "=== $(basename "$bench")" >&2
  "$bench" "$@"
  echo >&2
done
