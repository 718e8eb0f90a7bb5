"""A classifier two-sample test: can a simple model tell real patches from synthetic ones?

Square in-slice patches of the same size are cut from both volumes' bulk regions
(`synthpack.realism.patches`) and mapped through the same intensity window (the
source's 0.5 and 99.5 percentiles, as the YOLO export does) to [0, 1]. Each patch
is described by features that say how it looks, not where its grains are:

* the histogram of its intensities (16 bins on [0, 1]): grey levels and contrast;
* the histogram of the absolute differences between neighbouring pixels (16 bins
  on [0, 0.5]): noise level and edge sharpness;
* the log of its radially averaged power spectrum (mean removed): noise texture
  and blur.

A logistic regression (features standardised) is trained to tell the two sets
apart and scored by the area under the ROC curve with stratified k-fold
cross-validation (scikit-learn). An AUC of 0.5 means the classifier does no
better than chance: the patches are indistinguishable to it. 1 means it tells
every synthetic patch from every real one. It is a lower bound on how
distinguishable the volumes are: a stronger model might still tell them apart.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import SynthpackInputError
from .patches import patch_corners, take_patches
from .region import Specimen

logger = logging.getLogger(__name__)

__all__ = ["DEFAULT_PATCH", "classifier_auc", "patch_features", "specimen_patches"]

#: Default patch side, voxels.
DEFAULT_PATCH = 16
_BINS = 16


def specimen_patches(
    specimen: Specimen, window: tuple[float, float], *, size: int = DEFAULT_PATCH, max_patches: int = 600
) -> np.ndarray:
    """In-slice patches of a specimen's bulk region, windowed to [0, 1].

    Parameters
    ----------
    specimen : Specimen
    window : (float, float)
        Intensities ``lo`` and ``hi`` that map to 0 and 1 (values outside are clipped).
    size : int
        Patch side, voxels.
    max_patches : int
        At most this many, spread evenly over the region's slices. Corners lie on a
        lattice of half a patch, so neighbouring patches overlap by half.

    Returns
    -------
    ndarray of float32, shape (N, size, size)
    """
    corners = patch_corners(specimen.region, size, max(1, size // 2), max_patches)
    lo, hi = window
    patches = (take_patches(specimen.tomogram, corners, size) - np.float32(lo)) / np.float32(hi - lo)
    return np.clip(patches, 0.0, 1.0)


def patch_features(patches: np.ndarray) -> np.ndarray:
    """Appearance features of windowed patches (see the module docstring).

    Parameters
    ----------
    patches : ndarray, shape (N, S, S)
        Intensities in [0, 1].

    Returns
    -------
    ndarray of float64, shape (N, 32 + S // 2 + 1)
    """
    patches = np.asarray(patches, dtype=np.float64)
    n, size = patches.shape[0], patches.shape[1]

    def histograms(values: np.ndarray, top: float) -> np.ndarray:
        bins = np.clip((values / top * _BINS).astype(np.int64), 0, _BINS - 1)
        offsets = np.arange(n)[:, None] * _BINS
        counts = np.bincount((bins + offsets).ravel(), minlength=n * _BINS).reshape(n, _BINS)
        return counts / values.shape[1]

    differences = np.concatenate([np.abs(np.diff(patches, axis=1)).reshape(n, -1),
                                  np.abs(np.diff(patches, axis=2)).reshape(n, -1)], axis=1)
    centred = patches - patches.mean(axis=(1, 2), keepdims=True)
    power = np.abs(np.fft.fft2(centred)) ** 2 / size**4
    frequency = np.fft.fftfreq(size)
    ring = np.rint(np.hypot(frequency[:, None], frequency[None, :]) * size).astype(np.int64).ravel()
    keep = ring <= size // 2
    spectrum = np.stack([np.bincount(ring[keep], weights=p.ravel()[keep], minlength=size // 2 + 1) for p in power])
    return np.concatenate([histograms(patches.reshape(n, -1), 1.0), histograms(differences, 0.5),
                           np.log10(spectrum + 1e-12)], axis=1)


def classifier_auc(real: np.ndarray, synthetic: np.ndarray, *, folds: int = 5, seed: int = 0) -> dict:
    """Cross-validated ROC AUC of a logistic regression telling `real` from `synthetic` patches.

    Both sets are cut to the same size (an even subset of the larger one) so that
    the classes are balanced.

    Parameters
    ----------
    real, synthetic : ndarray, shape (N, S, S) and (M, S, S)
        Windowed patches (`specimen_patches`), the same S.
    folds : int
        Stratified cross-validation folds (>= 2).
    seed : int
        Seed of the fold shuffling.

    Returns
    -------
    dict
        ``auc`` (mean over folds), ``auc_std`` (spread over folds), ``n_per_class``.

    Raises
    ------
    SynthpackInputError
        If the patch sizes differ or a set has fewer than ``2 * folds`` patches.
    """
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import StratifiedKFold, cross_val_score
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    if real.shape[1:] != synthetic.shape[1:]:
        raise SynthpackInputError(f"patches differ in size: {real.shape[1:]} and {synthetic.shape[1:]}")
    n = min(len(real), len(synthetic))
    if n < 2 * folds:
        raise SynthpackInputError(
            f"only {n} patches per class for a {folds}-fold classifier test: "
            "measure bigger volumes or use smaller patches"
        )
    take = [np.linspace(0, len(s) - 1, n).astype(np.int64) for s in (real, synthetic)]
    features = np.concatenate([patch_features(real[take[0]]), patch_features(synthetic[take[1]])])
    target = np.repeat([0, 1], n)
    model = make_pipeline(StandardScaler(), LogisticRegression(C=1.0, max_iter=2000))
    scores = cross_val_score(model, features, target, scoring="roc_auc",
                             cv=StratifiedKFold(n_splits=folds, shuffle=True, random_state=seed))
    logger.info("classifier AUC %.3f +- %.3f (%d patches per class)", scores.mean(), scores.std(), n)
    return {"auc": float(scores.mean()), "auc_std": float(scores.std()), "n_per_class": int(n)}
