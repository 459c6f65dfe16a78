#!/usr/bin/env bash
# Runs every benchmark program (heavy; not part of the tests or CI). Each prints its
# comparison with a peer run in the same process and a summary of the ratios.
set -euo pipefail
# recognise_bench builds its ~12k-view database once (2–4 min) and caches it in
# $SOPE_BENCH_CACHE (default /tmp/sope-bench-cache); SOPE_BENCH_PASSES sets its passes over
# the queries (default 2). Pin to one core for the issue-4 numbers: taskset -c 1.
build=${1:-build}
for bench in "$build"/bench/*_bench; do
  [ -x "$bench" ] || continue
  echo "=== $(basename "$bench")"
  "$bench"
  echo
done
