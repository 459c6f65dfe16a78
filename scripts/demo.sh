#!/usr/bin/env bash
# The main job on its built-in default: the virtual rig. Renders a procedural scene,
# decodes and triangulates it, and leaves everything to look at in OUT.
set -euo pipefail
sope=${1:-build/app/sope}
out=${2:-out/demo}
mkdir -p "$out"
echo "== simulate: a sphere before a backdrop on the virtual rig"
"$sope" simulate --mesh builtin:sphere --object-size 0.2 --object-pose 0,0,0,0,0,0.58 \
  --backdrop 0.72 --out "$out/frames"
echo "== decode"
"$sope" decode --frames "$out/frames" --out "$out/maps"
echo "== scan"
"$sope" scan --frames "$out/frames" --out "$out/cloud.ply"
echo
echo "results in $out: frames/ (frame set + ground truth), maps/*.png (decoded maps), cloud.ply"
