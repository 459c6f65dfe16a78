#!/usr/bin/env bash
# Runs every benchmark program (heavy; not part of the tests or CI). Each prints its
# comparison with a peer run in the same process and a summary of the ratios.
set -euo pipefail
build=${1:-build}
for bench in "$build"/bench/*_bench; do
  [ -x "$bench" ] || continue
  echo "=== $(basename "$bench")"
  "$bench"
  echo
done
