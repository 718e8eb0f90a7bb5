"""Watershed labels of the concrete X-ray CT (../shared/data/concrete/concrete_xray.tif), as a user would make them.

The X-ray scan comes without labels (its README). These are not ground truth: a scan that
nobody tuned synthpack to, labelled the way a user's first watershed would be, for the realism
check of docs/realism-concrete.md. The aggregates are brighter than the paste there (the
neutron scan has them darker), at about a sixth of its contrast, in a cylinder with voids.

Recipe: a Gaussian of 0.8 voxel; the specimen's radial trend (the median of each 2-voxel ring
within 42 voxels of the axis, slices 6-93) divided out; Otsu's threshold between paste and
aggregates (the voids, below 0.97 of the trend, left out of it); an opening by a ball of 1, holes
filled, objects under 30 voxels removed; a distance-transform watershed from the maxima of the
smoothed distance (at least 3 voxels apart); labels under 20 voxels removed.

Usage (from the repository root; the labels are written outside the repository, as the scan is GPL)::

    .venv/bin/python docs/label_concrete_xray.py /tmp/concrete_xray_labels.tif
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage
from skimage import feature, filters, measure, morphology, segmentation

SCAN = Path(__file__).resolve().parents[2] / "shared" / "data" / "concrete" / "concrete_xray.tif"


def label_xray(tomogram: np.ndarray) -> np.ndarray:
    """Instance labels (uint16, 0 = paste, voids and outside) of the X-ray scan's aggregates (module docstring)."""
    smooth = ndimage.gaussian_filter(tomogram.astype(np.float32), 0.8)
    z, y, x = np.indices(smooth.shape)
    centre = smooth.shape[1] // 2, smooth.shape[2] // 2
    radius = np.hypot(y - centre[0], x - centre[1])
    inside = (radius < 42) & (z >= 6) & (z < smooth.shape[0] - 6)
    ring = np.minimum((radius / 2).astype(int), 25)
    profile = np.array([np.median(smooth[inside & (ring == k)]) if (inside & (ring == k)).any() else np.nan
                        for k in range(26)])
    profile = np.where(np.isnan(profile), np.nanmin(profile), profile)
    ratio = smooth / profile[ring]
    threshold = filters.threshold_otsu(ratio[inside & (ratio > 0.97)])
    grain = ndimage.binary_opening((ratio > threshold) & inside, morphology.ball(1))
    grain = ndimage.binary_fill_holes(grain)
    grain = morphology.remove_small_objects(grain, max_size=29)
    distance = ndimage.distance_transform_edt(grain)
    peaks = feature.peak_local_max(ndimage.gaussian_filter(distance, 1), min_distance=3,
                                   labels=measure.label(grain), exclude_border=False)
    markers = np.zeros(distance.shape, np.int32)
    markers[tuple(peaks.T)] = np.arange(1, len(peaks) + 1)
    labels = segmentation.watershed(-distance, markers, mask=grain)
    labels = morphology.remove_small_objects(labels, max_size=19)
    return segmentation.relabel_sequential(labels)[0].astype(np.uint16)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: label_concrete_xray.py OUT.tif (outside the repository: the scan is GPL)")
    labels = label_xray(tifffile.imread(SCAN))
    tifffile.imwrite(sys.argv[1], labels)
    print(f"{labels.max()} labels, {np.count_nonzero(labels) / labels.size:.3f} of the volume")
