#!/usr/bin/env bash
# The realism figures of docs/realism-concrete.md and docs/realism-sand.md: per real scan in
# ../shared/data, a default (calibrated) pack and a `postprocess: none` pack of the same pour,
# then `synthpack compare` of both against the scan. Not a test (about 15 minutes on 2 cores).
# Usage: bash docs/realism-real-scans.sh OUT   (from the repository root, with .venv installed)
set -euo pipefail
OUT=${1:?usage: docs/realism-real-scans.sh OUT}
D=${SYNTHPACK_SHARED_DATA:-../shared/data}
PY=${PYTHON:-.venv/bin/python}
mkdir -p "$OUT"
printf 'postprocess: none\n' > "$OUT/none.yaml"
run() { # name tomogram labels n_particles
  local name=$1 n=$4 S="--tomogram $2 --labels $3 --voxel-size 1 --unit px"
  mkdir -p "$OUT/$name"
  $PY -m synthpack generate $S --n-particles "$n" --batch-size 50 --workers 0 --out "$OUT/$name/calibrated"
  $PY -m synthpack generate $S --n-particles "$n" --batch-size 50 --workers 0 --config "$OUT/none.yaml" \
      --out "$OUT/$name/none"
  $PY -m synthpack compare $S --packs "$OUT/$name/calibrated" "$OUT/$name/none" --out "$OUT/$name/report"
}
run concrete "$D/concrete/concrete_neutron.tif" "$D/concrete/concrete_neutron_labels_watershed.tif" 300
run sand "$D/sand/sand.tif" "$D/sand/sand_labels_watershed.tif" 400
