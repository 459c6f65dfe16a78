#!/usr/bin/env bash
# Reproduces the recogniser's evaluation figures (README "Recognition"): both protocols,
# our method beside the thesis preset. Heavy (~50 min on 2 cores): not part of CI.
#   scripts/evaluate.sh [SOPE] [OUT] [DATA]
set -euo pipefail
sope=${1:-build/app/sope}
out=${2:-out/eval}
data=${3:-../shared/data}
mkdir -p "$out"

# Class protocol: 16 training instances of each of the 10 procedural classes (seeds 100–115;
# the default database's count) in the database, 3 unseen instances per class (seeds
# 1000–1002) as queries.
[ -d "$out/train" ] || "$sope" objects --instances 16 --seed 100 --out "$out/train"
[ -d "$out/held_out" ] || "$sope" objects --instances 3 --seed 1000 --out "$out/held_out"
[ -f "$out/class.sopedb" ] || "$sope" build-db --models "$out/train" --views 150 --out "$out/class.sopedb"
[ -f "$out/class_thesis.sopedb" ] || "$sope" build-db --models "$out/train" --preset thesis --out "$out/class_thesis.sopedb"
"$sope" eval --db "$out/class.sopedb" --models "$out/held_out" --queries-per-model 6 \
  --grouping class --out "$out/class_sope"
"$sope" eval --db "$out/class_thesis.sopedb" --models "$out/held_out" --queries-per-model 6 \
  --method thesis --grouping class --out "$out/class_thesis"
# Before class-aware ranking (issue 16), the same database and queries.
"$sope" eval --db "$out/class.sopedb" --models "$out/held_out" --queries-per-model 6 \
  --grouping class --no-class-ranking --out "$out/class_sope_no_class_ranking"
# Class ranking without class screening (--class-screen-classes 0, the vote weight of before).
"$sope" eval --db "$out/class.sopedb" --models "$out/held_out" --queries-per-model 6 \
  --grouping class --class-screen-classes 0 --class-vote-weight 0.1 \
  --out "$out/class_sope_no_class_screening"
# The same queries scanned through the full pipeline on the virtual rig, with the same
# occluder (its share of the scanned points hidden), with and without class-aware ranking.
"$sope" eval --db "$out/class.sopedb" --models "$out/held_out" --queries-per-model 6 \
  --grouping class --scan-pipeline --scan-occlusion --out "$out/class_sope_scan"
"$sope" eval --db "$out/class.sopedb" --models "$out/held_out" --queries-per-model 6 \
  --grouping class --scan-pipeline --scan-occlusion --no-class-ranking \
  --out "$out/class_sope_scan_no_class_ranking"

# Instance protocol on the shared meshes (YCB + classic), when present.
if [ -d "$data/meshes" ]; then
  [ -f "$out/instance.sopedb" ] || "$sope" build-db --models "$data/meshes" --out "$out/instance.sopedb"
  [ -f "$out/instance_thesis.sopedb" ] || "$sope" build-db --models "$data/meshes" --preset thesis --out "$out/instance_thesis.sopedb"
  for occlusion in 0.25 0; do
    "$sope" eval --db "$out/instance.sopedb" --queries-per-model 10 --occlusion $occlusion \
      --out "$out/instance_sope_occ$occlusion"
    "$sope" eval --db "$out/instance_thesis.sopedb" --queries-per-model 10 --method thesis \
      --occlusion $occlusion --out "$out/instance_thesis_occ$occlusion"
  done
  "$sope" eval --db "$out/instance.sopedb" --queries-per-model 10 --scan-pipeline \
    --out "$out/instance_sope_scan"
else
  echo "no $data/meshes: instance protocol skipped"
fi
echo "reports: $out/*/report.md"
