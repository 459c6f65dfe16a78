#!/usr/bin/env bash
# The main job on its built-in default: the virtual rig. Renders a procedural scene,
# decodes and triangulates it, then scans and recognises tables of procedural household
# objects (sope scan-and-recognise --virtual --table) and single objects (--virtual), and
# leaves everything to look at in OUT.
set -euo pipefail
sope=${1:-build/app/sope}
out=${2:-out/demo}
mkdir -p "$out"
echo "== simulate: a table with four household objects and an unknown stone on the virtual rig"
"$sope" simulate --table --mesh builtin:mug:1003 --mesh builtin:bowl:1004 \
  --mesh builtin:bottle:1005 --mesh builtin:can:1006 --clutter 1 --seed 3 --out "$out/frames"
echo "== decode"
"$sope" decode --frames "$out/frames" --out "$out/maps"
echo "== scan"
"$sope" scan --frames "$out/frames" --out "$out/cloud.ply"
echo "== scan and recognise: 2 tables of 3-5 household objects, each segmented, named and"
echo "   posed (the first run builds the default database, ~5 CPU-minutes, cached in"
echo "   \${XDG_CACHE_HOME:-~/.cache}/sope; the objects are the database's own instances)"
rm -rf "$out/table" "$out/recognise"  # results.jsonl would otherwise collect every run
"$sope" scan-and-recognise --virtual --table --instances database --seed 3 --scans 2 \
  --out "$out/table"
echo "== scan and recognise: 3 unseen procedural objects in random poses, one at a time"
"$sope" scan-and-recognise --virtual --scans 3 --out "$out/recognise"
echo
echo "results in $out: frames/ (frame set + ground truth: gt_objects.png names every object,"
echo "  gt_pose.json lists them), maps/*.png (decoded maps), cloud.ply,"
echo "  table/: per tabletop scan scan_NNNN_overlay.png (every recognised object drawn and"
echo "  named, the others marked unknown), the clouds and results.jsonl (objects[] per scan),"
echo "  recognise/: per scan the cloud (scan_NNNN.ply, scan_NNNN_object.ply), the overlay"
echo "  (scan_NNNN_overlay.png: the recognised model drawn on the camera image) and"
echo "  results.jsonl (one JSON recognition result per scan, with timings and ground truth)"
