#!/usr/bin/env bash
# Scans nobody tuned to, made from the sand micro-CT in ../shared/data (MIT): the figures of
# docs/realism-sand.md's "Variants of the scan" section. Each variant is written to OUT (never
# into the repository), then a default (calibrated) and a `postprocess: none` pack of the same
# pour are made and compared with it, as docs/realism-real-scans.sh does. Not a test (about
# 40 minutes on 2 cores). Usage: bash docs/realism-variants.sh OUT [VARIANT ...]   (from the repository
# root; the named variants only, e.g. up2 flt, or all of them)
set -euo pipefail
OUT=${1:?usage: docs/realism-variants.sh OUT [VARIANT ...]}
shift
ONLY=" $* "
D=${SYNTHPACK_SHARED_DATA:-../shared/data}
PY=${PYTHON:-.venv/bin/python}
mkdir -p "$OUT/scans"
printf 'postprocess: none\n' > "$OUT/none.yaml"
"$PY" - "$D/sand" "$OUT/scans" <<'PYTHON'
import sys
import numpy as np
import tifffile
from scipy import ndimage
from skimage.segmentation import relabel_sequential

source, out = sys.argv[1], sys.argv[2]
image = tifffile.imread(f"{source}/sand.tif").astype(np.float32)
labels = tifffile.imread(f"{source}/sand_labels_watershed.tif")
rng = np.random.default_rng(0)
z, y, x = image.shape


def write(name, tomogram, mask):
    tifffile.imwrite(f"{out}/{name}.tif", tomogram)
    tifffile.imwrite(f"{out}/{name}_labels.tif", relabel_sequential(mask)[0].astype(np.uint16))


# bin2: 2x2x2 binned to 16 bit (grains about 7.6 voxels across, too thin for a noise spectrum at the PSF's reach)
write("bin2", np.round(200 * image.reshape(z // 2, 2, y // 2, 2, x // 2, 2).mean(axis=(1, 3, 5))).astype(np.uint16),
      labels[::2, ::2, ::2])
# inv: grains darker than the pores, ten times the noise, 8 bit
write("inv", np.clip(255 - image + rng.normal(0, 10, image.shape), 0, 255).astype(np.uint8), labels)
# cyl: a cylinder of sand in air (no container): the tube view, not an interior crop
outside = np.broadcast_to((np.arange(y)[:, None] - (y - 1) / 2) ** 2 + (np.arange(x)[None] - (x - 1) / 2) ** 2
                          > (0.45 * y) ** 2, image.shape)
cylinder = image.copy()
cylinder[outside] = 5 + rng.normal(0, 3, np.count_nonzero(outside))
write("cyl", np.clip(cylinder, 0, 255).astype(np.uint8), np.where(outside, 0, labels))
# flt: float32 attenuation-like values (x 2e-4, offset): no integer grey levels
write("flt", (image * 2e-4 - 0.005).astype(np.float32), labels)
# aniso: slices 2 voxels apart along z (voxel 2 x 1 x 1)
write("aniso", np.round(image.reshape(z // 2, 2, y, x).mean(axis=1)).astype(np.uint8), labels[::2])
# up2: 2x finer voxel (cubic), fresh noise: grains about 34 voxels across
finer = ndimage.zoom(image, 2, order=3) + np.random.default_rng(1).normal(0, 4, (2 * z, 2 * y, 2 * x))
write("up2", np.clip(finer, 0, 255).astype(np.uint8), ndimage.zoom(labels, 2, order=0))
PYTHON
run() { # name n_particles voxel_size...
  local name=$1 n=$2; shift 2
  [[ "$ONLY" == "  " || "$ONLY" == *" $name "* ]] || return 0
  local S="--tomogram $OUT/scans/$name.tif --labels $OUT/scans/${name}_labels.tif --voxel-size $* --unit px"
  mkdir -p "$OUT/$name"
  $PY -m synthpack generate $S --n-particles "$n" --batch-size 50 --workers 0 --out "$OUT/$name/calibrated"
  $PY -m synthpack generate $S --n-particles "$n" --batch-size 50 --workers 0 --config "$OUT/none.yaml" \
      --out "$OUT/$name/none"
  $PY -m synthpack compare $S --packs "$OUT/$name/calibrated" "$OUT/$name/none" --out "$OUT/$name/report"
}
run bin2 600 1
run inv 400 1
run cyl 300 1
run flt 400 1
run aniso 400 2 1 1
run up2 auto 1
