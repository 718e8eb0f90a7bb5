"""Starting instance labels for a scan that has none, the classical way.

`label_scan` segments the grains of a tomogram with no labels, so that a user with only
a scan can run the whole pipeline, and correct the labels afterwards (in Fiji, ilastik,
napari, ...). The labels are a STARTING POINT TO CHECK AND CORRECT, NOT GROUND TRUTH:
touching grains may be merged or a grain split in two, and every such error is copied
into the particle library built from them.

The steps (scikit-image and SciPy, settings in `LabelConfig`):

1. **Denoise.** A Gaussian filter of `sigma` voxels (0: none). It is kept light by
   default (0.5 voxel): a heavier blur fills the thin dark gaps at grain contacts that
   the watershed needs less, but the threshold then loses contacts on grains only a few
   voxels across.
2. **Threshold.** `threshold` when given, else Otsu's threshold of the denoised volume
   (`skimage.filters.threshold_otsu`).
3. **Contrast.** ``"bright"``: the grains are the voxels above the threshold (X-ray CT:
   grains attenuate more than the pore space); ``"dark"``: below it (an inverted scan, or
   neutron CT of a hydrogenous pore fluid). ``"auto"`` takes the THICKER phase as the
   grains: the side of the threshold whose voxels are on average farther from the other
   side (the mean of each phase's Euclidean distance transform). In a pack the pore space
   is the narrow gaps between grains, so it is the thinner phase. This assumes the volume
   is a crop inside the specimen: air or a container around a whole specimen is thick
   too, so crop it away or give the contrast. When the two means differ by less than
   `_AUTO_MARGIN`, a warning says so.
4. **Markers.** The grain mask's Euclidean distance transform, smoothed with a Gaussian
   of `smoothing` voxels; one marker per local maximum of it at least `min_distance`
   voxels from a higher one (`skimage.feature.peak_local_max`, which keeps the highest
   of maxima closer than that). By default `min_distance` is the mean distance of the
   grain voxels to the pores, rounded (at least 1): a fraction of a grain radius, so a
   grain's one central ridge gives one marker while the neck at a contact between two
   grains does not.
5. **Watershed.** `skimage.segmentation.watershed` of the negated smoothed distance from
   the markers, inside the grain mask: each grain voxel goes to the marker it drains to.
6. **Clean-up.** Grains of fewer than `min_voxels` voxels become pore, and the labels
   are renumbered 1..N (`skimage.segmentation.relabel_sequential`).

Memory: about 30 bytes per voxel at the peak (the float32 denoised volume, the float64
distance transforms and the int32 labels), all in memory at once.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._shared.budget import LABEL_BYTES_PER_VOXEL, check_volume
from .._shared.schema import finite, non_negative, one_of, positive, setting
from ..errors import SynthpackInputError
from .core import validate_tomogram

logger = logging.getLogger(__name__)

__all__ = ["CONTRASTS", "STARTING_POINT", "LabelConfig", "Labelling", "label_scan"]

#: The sides of the threshold the grains can be on (``auto``: the thicker phase).
CONTRASTS = ("auto", "bright", "dark")

#: ``auto`` warns when the thicker phase is thicker by less than this fraction.
_AUTO_MARGIN = 0.1

#: The warning every labelling carries.
STARTING_POINT = ("these labels are a starting point made by a threshold and a watershed, not ground truth: "
                  "check and correct them (merged or split grains) before building a library from them")


@dataclass(frozen=True)
class LabelConfig:
    """Settings of `label_scan` (see the module docstring for the steps).

    Attributes
    ----------
    threshold : float or None
        Grey value between pores and grains, in the tomogram's units; None: Otsu's
        threshold of the denoised volume.
    contrast : {"auto", "bright", "dark"}
        Which side of the threshold the grains are on.
    sigma : float
        Standard deviation of the Gaussian denoising, voxels (0: none).
    smoothing : float
        Standard deviation of the Gaussian smoothing of the distance transform, voxels.
    min_distance : int or None
        Least distance between two markers, voxels; None: the mean distance of the
        grain voxels to the pores, rounded.
    min_voxels : int
        Grains smaller than this many voxels become pore.
    """

    threshold: float | None = setting(
        None, finite, "grey value between pores and grains (default: Otsu's threshold of the denoised scan)")
    contrast: str = setting(
        "auto", one_of(CONTRASTS),
        "grains brighter than the pores (bright), darker (dark), or the thicker phase (auto)")
    sigma: float = setting(0.5, non_negative, "Gaussian denoising before the threshold, voxels (0: none)")
    smoothing: float = setting(1.0, non_negative, "Gaussian smoothing of the distance transform, voxels (0: none)")
    min_distance: int | None = setting(
        None, positive,
        "least distance between two grain markers, voxels (default: the grains' mean distance to the pores)")
    min_voxels: int = setting(10, positive, "grains smaller than this many voxels become pore")


@dataclass(frozen=True)
class Labelling:
    """What `label_scan` found, and the values it chose.

    Attributes
    ----------
    labels : ndarray of int32, shape (Z, Y, X)
        0 = pore, 1..N = grains.
    threshold : float
        The threshold used, in the tomogram's units.
    contrast : {"bright", "dark"}
        The side of the threshold taken as grains.
    min_distance : int
        The least marker distance used, voxels.
    """

    labels: np.ndarray
    threshold: float
    contrast: str
    min_distance: int

    @property
    def n_grains(self) -> int:
        """Number of grains labelled."""
        return int(self.labels.max())


def label_scan(tomogram: np.ndarray, settings: LabelConfig | None = None) -> Labelling:
    """Label the grains of a tomogram by threshold and distance-transform watershed.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Reconstructed intensities (any real dtype).
    settings : LabelConfig, optional
        Denoising, threshold, contrast and marker settings; the defaults when None.

    Returns
    -------
    Labelling
        The labels (int32, 0 = pore) and the threshold, contrast and marker distance used.

    Raises
    ------
    SynthpackInputError
        If the tomogram is not a finite real 3D volume, has no contrast (one grey value
        throughout), the threshold leaves no voxel on one of its sides, or no grain is left.

    Notes
    -----
    The labels are a starting point to check and correct, not ground truth; a warning
    says so on every call.
    """
    from skimage.filters import threshold_otsu

    settings = settings or LabelConfig()
    check_volume(np.shape(tomogram), LABEL_BYTES_PER_VOXEL, "labelling", "crop the volume first")
    volume = validate_tomogram(tomogram).astype(np.float32, copy=False)
    low, high = float(volume.min()), float(volume.max())
    if low == high:
        raise SynthpackInputError(
            f"the scan has no contrast: every voxel is {low:.6g}, so no threshold separates grains from pores; "
            "check that the tomogram file is the reconstructed scan, not a blank or a mask"
        )
    denoised = ndimage.gaussian_filter(volume, settings.sigma) if settings.sigma else volume
    threshold = float(threshold_otsu(denoised)) if settings.threshold is None else float(settings.threshold)
    bright = denoised > threshold
    n_bright = int(np.count_nonzero(bright))
    if n_bright in (0, bright.size):
        side = "above" if n_bright == 0 else "at or below"
        raise SynthpackInputError(
            f"no voxel of the denoised scan is {side} the threshold {threshold:.6g} (grey values "
            f"{float(denoised.min()):.6g} to {float(denoised.max()):.6g}): give a --threshold between them"
        )
    del denoised
    contrast = _choose_contrast(bright) if settings.contrast == "auto" else settings.contrast
    grains = bright if contrast == "bright" else ~bright
    labels, min_distance = _watershed(grains, settings)
    if labels.max() == 0:
        raise SynthpackInputError(
            f"no grain of {settings.min_voxels} voxels or more was found (threshold {threshold:.6g}, "
            f"{contrast} grains): check --contrast, --threshold and --min-voxels"
        )
    logger.info("labelled %d grains: threshold %.6g, %s grains, markers at least %d voxels apart",
                int(labels.max()), threshold, contrast, min_distance)
    logger.warning(STARTING_POINT)
    return Labelling(labels=labels, threshold=threshold, contrast=contrast, min_distance=min_distance)


def _choose_contrast(bright: np.ndarray) -> str:
    """``"bright"`` or ``"dark"``: the side of the threshold with the larger mean distance to the other."""
    thickness = {side: float(ndimage.distance_transform_edt(mask)[mask].mean())
                 for side, mask in (("bright", bright), ("dark", ~bright))}
    grains = max(thickness, key=thickness.get)
    pores = "dark" if grains == "bright" else "bright"
    logger.info("contrast auto: the %s phase is thicker (mean distance to the other phase %.2f against %.2f "
                "voxels), taken as the grains", grains, thickness[grains], thickness[pores])
    if thickness[grains] < (1 + _AUTO_MARGIN) * thickness[pores]:
        logger.warning("contrast auto is unsure: the bright and dark phases are about as thick (mean distance "
                       "%.2f and %.2f voxels); check the labels, or give --contrast bright or dark",
                       thickness["bright"], thickness["dark"])
    return grains


def _watershed(grains: np.ndarray, settings: LabelConfig) -> tuple[np.ndarray, int]:
    """Labels (int32) of the grain mask by the distance-transform watershed, and the marker distance used."""
    from skimage.feature import peak_local_max
    from skimage.segmentation import relabel_sequential, watershed

    distance = ndimage.distance_transform_edt(grains)
    min_distance = settings.min_distance or max(1, round(float(distance[grains].mean())))
    if settings.smoothing:
        distance = ndimage.gaussian_filter(distance, settings.smoothing)
    peaks = peak_local_max(distance, min_distance=min_distance, labels=grains, exclude_border=False)
    markers = np.zeros(grains.shape, dtype=np.int32)
    markers[tuple(peaks.T)] = np.arange(1, len(peaks) + 1, dtype=np.int32)
    labels = watershed(-distance, markers, mask=grains)
    labels[(np.bincount(labels.ravel()) < settings.min_voxels)[labels]] = 0
    return relabel_sequential(labels)[0].astype(np.int32, copy=False), min_distance
