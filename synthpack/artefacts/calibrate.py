"""Measure the noise of a labelled tomogram, and the Gaussian noise that matches a source scan.

The estimator (after Immerkaer, "Fast noise variance estimation", CVIU 1996,
extended to 3D) filters the image with the separable second difference
``[1, -2, 1]`` along every axis. That filter removes any intensity that varies
smoothly (every polynomial of degree < 2 in some axis, so constant grains, linear
ramps and gentle low-frequency texture), while white noise of standard deviation
``s`` comes out with standard deviation ``s * 6^(ndim/2)``. The filter is only
evaluated inside each phase, away from edges: a voxel counts if every voxel within
`margin` of it (a cube) carries the same label, so grain boundaries, grain-grain
contacts and partial-volume edges do not contribute. The standard deviation is
then taken robustly, ``1.4826 * MAD``, which is exact for Gaussian noise and
insensitive to the odd outlier.

Noise that is spatially correlated (e.g. after blur or reconstruction filtering)
has less power at the highest frequencies, so the estimate is then the standard
deviation of the white noise with the same high-frequency content: exactly what
is needed to match it with `GaussianNoise` on a volume whose own noise is white.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from scipy import ndimage

from ..errors import SynthpackInputError
from ._arrays import SLAB_VOXELS, as_image, slabs
from .noise import GaussianNoise

logger = logging.getLogger(__name__)

__all__ = ["estimate_noise", "matched_noise", "noise_to_add"]

#: A phase needs at least this many interior voxels for its noise estimate.
MIN_SAMPLES = 200

_MAD_TO_STD = 1.482602218505602  # 1 / Phi^-1(3/4)


def _robust_std(values: np.ndarray) -> float:
    deviation = np.abs(values - np.median(values))
    return float(_MAD_TO_STD * np.median(deviation))


def _second_difference(block: np.ndarray) -> np.ndarray:
    """``[1, -2, 1]`` along every axis of `block` (float32), divided by its gain ``6^(ndim/2)``."""
    out = block
    for axis in range(block.ndim):
        out = ndimage.correlate1d(out, [1.0, -2.0, 1.0], axis=axis, output=np.float32, mode="nearest")
    out /= np.float32(6.0 ** (block.ndim / 2.0))
    return out


def _interior(labels: np.ndarray, margin: int) -> np.ndarray:
    """True where every voxel within `margin` (a cube) has the same label."""
    size = 2 * margin + 1
    low = ndimage.minimum_filter(labels, size=size, mode="nearest")
    high = ndimage.maximum_filter(labels, size=size, mode="nearest")
    return low == high


def _check_inputs(tomogram: Any, labels: Any, margin: int) -> tuple[np.ndarray, np.ndarray]:
    image = as_image(tomogram)
    label_array = np.asarray(labels)
    if label_array.shape != image.shape:
        raise SynthpackInputError(
            f"the tomogram has shape {image.shape} but the labels {label_array.shape}: "
            "pass the label volume that belongs to this tomogram"
        )
    if not (np.issubdtype(label_array.dtype, np.integer) or label_array.dtype == bool):
        raise SynthpackInputError(
            f"labels must be integers (0 = pore, > 0 = grain), got dtype {label_array.dtype}"
        )
    if isinstance(margin, bool) or not isinstance(margin, (int, np.integer)) or margin < 1:
        raise SynthpackInputError(f"margin must be an integer >= 1 (voxels), got {margin!r}")
    return image, label_array.astype(np.int64, copy=False)


def estimate_noise(
    tomogram: np.ndarray,
    labels: np.ndarray,
    *,
    margin: int = 2,
    max_samples: int = 4_000_000,
) -> dict[str, Any]:
    """Estimate the standard deviation of the noise in grains and in pores.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X) or (H, W)
        Intensities (any real dtype).
    labels : ndarray of int, same shape
        0 for pore, > 0 for grains (each grain its own label).
    margin : int
        Voxels kept clear of every label boundary (>= 1). Default 2, which keeps
        the 3 x 3 x 3 filter and a voxel of partial-volume blur inside one phase.
    max_samples : int
        Use at most about this many voxels (every k-th interior voxel) to keep
        memory bounded on big volumes. Default 4 million.

    Returns
    -------
    dict
        ``"std"``: the noise standard deviation in intensity units, pooled over
        both phases (root of the sample-weighted mean variance);
        ``"grain_std"``, ``"pore_std"``: per phase, None where a phase has fewer than
        `MIN_SAMPLES` interior voxels; ``"n_grain"``, ``"n_pore"``: voxels used.

    Raises
    ------
    SynthpackInputError
        If shapes differ, labels are not integers, or neither phase has enough
        interior voxels (then lower `margin`).
    """
    image, label_array = _check_inputs(tomogram, labels, margin)
    step = max(1, math.ceil(image.size / max_samples))
    halo = margin + 1
    grain_parts: list[np.ndarray] = []
    pore_parts: list[np.ndarray] = []
    # 3D: slabs along z with a halo, so memory stays a few slabs; 2D: one block.
    cores = slabs(image.shape, SLAB_VOXELS) if image.ndim == 3 else [slice(0, image.shape[0])]
    for core in cores:
        start, stop = max(core.start - halo, 0), min(core.stop + halo, image.shape[0])
        block_labels = label_array[start:stop]
        keep = _interior(block_labels, margin)
        highpass = _second_difference(image[start:stop])
        # drop the halo and the outermost voxel of the whole image (the filter needs neighbours)
        inner = (slice(core.start - start, core.stop - start),)
        keep, highpass, block_labels = keep[inner], highpass[inner], block_labels[inner]
        keep[:, [0, -1]] = False
        keep[..., [0, -1]] = False
        if core.start == 0:
            keep[0] = False
        if core.stop == image.shape[0]:
            keep[-1] = False
        grain_parts.append(highpass[keep & (block_labels > 0)][::step])
        pore_parts.append(highpass[keep & (block_labels == 0)][::step])
    grain = np.concatenate(grain_parts)
    pore = np.concatenate(pore_parts)
    stds = {
        phase: (_robust_std(values) if values.size >= MIN_SAMPLES else None)
        for phase, values in (("grain", grain), ("pore", pore))
    }
    counts = {"grain": int(grain.size), "pore": int(pore.size)}
    used = [(stds[k], counts[k]) for k in stds if stds[k] is not None]
    if not used:
        raise SynthpackInputError(
            f"too few voxels lie at least {margin} voxel(s) inside a grain or a pore "
            f"({counts['grain']} grain, {counts['pore']} pore; {MIN_SAMPLES} needed) to estimate "
            "the noise: lower margin or pass a bigger volume"
        )
    pooled = math.sqrt(sum(s * s * n for s, n in used) / sum(n for _, n in used))
    logger.info(
        "noise estimate: %.4g (grain %s, pore %s; %d + %d voxels)",
        pooled, stds["grain"], stds["pore"], counts["grain"], counts["pore"],
    )
    return {
        "std": pooled,
        "grain_std": stds["grain"],
        "pore_std": stds["pore"],
        "n_grain": counts["grain"],
        "n_pore": counts["pore"],
    }


def matched_noise(
    source_tomogram: np.ndarray,
    source_labels: np.ndarray,
    clean_tomogram: np.ndarray,
    clean_labels: np.ndarray,
    *,
    margin: int = 2,
) -> GaussianNoise:
    """The Gaussian noise that brings a clean synthetic volume to the source scan's noise level.

    Noise variances add, so the extra standard deviation is
    ``sqrt(max(source_std^2 - clean_std^2, 0))`` with both measured by
    `estimate_noise` (pooled over grains and pores).

    Parameters
    ----------
    source_tomogram, source_labels : ndarray, shape (Z, Y, X) or (H, W)
        The real scan and its labels.
    clean_tomogram, clean_labels : ndarray, shape (Z', Y', X') or (H', W')
        The synthetic volume before post-processing, and its labels.
    margin : int
        Passed to `estimate_noise`.

    Returns
    -------
    GaussianNoise
        With a fixed `std` (0 when the clean volume is already as noisy).
    """
    source = estimate_noise(source_tomogram, source_labels, margin=margin)["std"]
    clean = estimate_noise(clean_tomogram, clean_labels, margin=margin)["std"]
    return noise_to_add(source, clean)


def noise_to_add(source: float, clean: float) -> GaussianNoise:
    """Gaussian noise of std ``sqrt(max(source^2 - clean^2, 0))``: variances add.

    Parameters
    ----------
    source, clean : float
        Noise standard deviations (as `estimate_noise` measures them) of the real
        scan and of the clean synthetic volume, in intensity units.
    """
    std = math.sqrt(max(source * source - clean * clean, 0.0))
    if source <= clean:
        logger.warning(
            "the clean volume (noise %.4g) is already at least as noisy as the source (%.4g): "
            "no noise added", clean, source,
        )
    logger.info("matched noise: source %.4g, clean %.4g -> add std %.4g", source, clean, std)
    return GaussianNoise(std=std)
