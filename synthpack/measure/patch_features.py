"""How in-slice patches look, and how well a logistic regression tells two sets of them apart.

The realism report's logistic discriminator (`synthpack.realism.discriminator`) and the
calibration's guard (`synthpack.artefacts.guard`) read patches the same way: square
in-slice patches of `DEFAULT_PATCH` voxels on a lattice of half a patch
(`~synthpack.measure.lattice.patch_corners`), mapped through the source's intensity window
to [0, 1], and described by `patch_features`: the histogram of their intensities, the
histogram of the absolute differences between neighbouring pixels, and the log of their
radially averaged power spectrum (`FEATURE_GROUPS`: the columns of each). `logistic_auc` is the
cross-validated area under the ROC curve of a logistic regression on those features: 0.5 when
the sets look alike to it, 1 when it tells every patch apart.

`PatchReference` is what a source scan keeps of this (`~synthpack.source.SourceStatistics`):
its window, the features of up to `MAX_PATCHES` of its patches, and its *floor*, the AUC of
its own even slabs of `DEFAULT_SLAB` slices against its odd ones (`slab_parity`; the
realism report's floor, `synthpack.realism.floor`). A pack whose AUC against the source is
within `LOGISTIC_AUC_MARGIN` of the floor meets the realism target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._shared.windows import intensity_window
from ..errors import SynthpackInputError
from .lattice import patch_corners, take_patches

__all__ = ["DEFAULT_PATCH", "DEFAULT_SLAB", "FEATURE_GROUPS", "FOLDS", "LOGISTIC_AUC_MARGIN", "MAX_PATCHES",
           "PatchReference",
           "balanced_folds", "logistic_auc", "logistic_fold_auc", "patch_features", "slab_parity",
           "windowed_patches"]

#: Default patch side, voxels.
DEFAULT_PATCH = 16
#: Default number of patches cut from a pack (an even subset of its region's lattice); a source gives twice as many.
MAX_PATCHES = 600
#: Default slab thickness of the floor, slices along z (`synthpack.realism.floor`).
DEFAULT_SLAB = 10
#: Stratified cross-validation folds of a classifier test.
FOLDS = 5
#: The realism target of the logistic AUC: at most the source's floor plus this.
LOGISTIC_AUC_MARGIN = 0.05
_BINS = 16
#: The columns of `patch_features` by what they describe: the intensity histogram (grey levels and
#: contrast), the histogram of neighbour differences (noise level, edge steepness) and the log power
#: spectrum's rings (texture, blur).
FEATURE_GROUPS = {"intensities": slice(0, _BINS), "differences": slice(_BINS, 2 * _BINS),
                  "spectrum": slice(2 * _BINS, None)}


def windowed_patches(volume: np.ndarray, region: np.ndarray, window: tuple[float, float], *,
                     size: int = DEFAULT_PATCH, max_patches: int = MAX_PATCHES) -> tuple[np.ndarray, np.ndarray]:
    """The in-slice patches of `volume` wholly inside `region`, windowed to [0, 1].

    Parameters
    ----------
    volume : array-like, shape (Z, Y, X)
    region : ndarray of bool, same shape
    window : (float, float)
        Intensities ``lo`` and ``hi`` that map to 0 and 1 (values outside are clipped).
    size : int
        Patch side, voxels.
    max_patches : int
        At most this many, spread evenly over the region's slices; corners on a lattice of half a patch.

    Returns
    -------
    patches : ndarray of float32, shape (N, size, size)
        N may be 0.
    corners : ndarray of int64, shape (N, 3)
        ``(z, y0, x0)`` of each patch's first voxel, in slice order.
    """
    corners = patch_corners(region, size, max(1, size // 2), max_patches)
    return _windowed(volume, corners, window, size), corners


def _windowed(volume: np.ndarray, corners: np.ndarray, window: tuple[float, float], size: int) -> np.ndarray:
    """The patches of `volume` at `corners`, mapped through `window` to [0, 1] (float32)."""
    lo, hi = window
    return np.clip((take_patches(volume, corners, size) - np.float32(lo)) / np.float32(hi - lo), 0.0, 1.0)


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


def slab_parity(z: np.ndarray, slab: int) -> np.ndarray:
    """0 for slices in the even slabs of `slab` slices (counted from slice 0), 1 for the odd ones.

    Parameters
    ----------
    z : ndarray of int, shape (N,)
        Slice indices.
    slab : int
        Slab thickness, slices (>= 1).

    Returns
    -------
    ndarray of int64, shape (N,)

    Examples
    --------
    >>> slab_parity(np.arange(7), 2).tolist()
    [0, 0, 1, 1, 0, 0, 1]
    """
    return (np.asarray(z, dtype=np.int64) // slab) % 2


def balanced_folds(first: int, second: int, *, folds: int = FOLDS,
                   seed: int = 0) -> tuple[list[np.ndarray], np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """Balanced classes and stratified folds for telling `first` items from `second`.

    The larger set is cut to an even subset of the smaller one's size.

    Parameters
    ----------
    first, second : int
        How many items each set has.
    folds : int
        Stratified, shuffled cross-validation folds (scikit-learn's ``StratifiedKFold``).
    seed : int
        Seed of the shuffling.

    Returns
    -------
    take : list of 2 ndarray of int64, each shape (n,)
        Which items of each set are kept.
    target : ndarray of int64, shape (2n,)
        0 for the first set's n, then 1 for the second's.
    splits : list of (ndarray, ndarray)
        ``(train, test)`` indices into the 2n kept items, per fold.

    Raises
    ------
    SynthpackInputError
        If a set has fewer than ``2 * folds`` items.
    """
    from sklearn.model_selection import StratifiedKFold

    n = min(first, second)
    if n < 2 * folds:
        raise SynthpackInputError(
            f"only {n} patches per class for a {folds}-fold classifier test: "
            "measure bigger volumes or use smaller patches"
        )
    take = [np.linspace(0, count - 1, n).astype(np.int64) for count in (first, second)]
    target = np.repeat([0, 1], n)
    splits = list(StratifiedKFold(n_splits=folds, shuffle=True, random_state=seed).split(np.zeros(2 * n), target))
    return take, target, splits


def logistic_fold_auc(features: np.ndarray, target: np.ndarray,
                      folds: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Held-out AUC of each fold of a logistic regression (features standardised) on `features`.

    Parameters
    ----------
    features : ndarray of float64, shape (M, F)
        `patch_features` of both sets.
    target : ndarray of int, shape (M,)
    folds : list of (ndarray, ndarray)
        ``(train, test)`` indices (`balanced_folds`).

    Returns
    -------
    ndarray of float64, shape (len(folds),)
    """
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import cross_val_score
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    model = make_pipeline(StandardScaler(), LogisticRegression(C=1.0, max_iter=2000))
    return cross_val_score(model, features, target, scoring="roc_auc", cv=folds)


def logistic_auc(first: np.ndarray, second: np.ndarray, *, folds: int = FOLDS, seed: int = 0) -> float:
    """Mean held-out AUC of a logistic regression telling `first` patch features from `second`.

    Parameters
    ----------
    first, second : ndarray of float64, shape (N, F) and (M, F)
        `patch_features` of each set.
    folds, seed
        As for `balanced_folds`.

    Returns
    -------
    float
        In [0, 1]; about 0.5 for sets that look alike.

    Raises
    ------
    SynthpackInputError
        If a set has fewer than ``2 * folds`` patches.
    """
    take, target, splits = balanced_folds(len(first), len(second), folds=folds, seed=seed)
    features = np.concatenate([first[take[0]], second[take[1]]])
    return float(logistic_fold_auc(features, target, splits).mean())


@dataclass(frozen=True)
class PatchReference:
    """What a source scan keeps of its patches for the logistic AUC of a pack against it.

    Attributes
    ----------
    window : (float, float)
        The source's intensity window (`~synthpack._shared.windows.intensity_window`), intensity units.
    features : ndarray of float64, shape (N, F)
        `patch_features` of up to `MAX_PATCHES` of its windowed patches, spread evenly over its region.
    floor : float
        The logistic AUC of its even slabs against its odd ones (see the module docstring).
    """

    window: tuple[float, float]
    features: np.ndarray
    floor: float

    @classmethod
    def measure(cls, tomogram: np.ndarray, region: np.ndarray, *, slab: int = DEFAULT_SLAB) -> PatchReference | None:
        """The reference of a source scan, read in `region`; None where too few patches fit for the floor.

        Parameters
        ----------
        tomogram : ndarray, shape (Z, Y, X)
        region : ndarray of bool, same shape
            Where patches may lie (the specimen).
        slab : int
            Slab thickness of the floor, slices.
        """
        window = intensity_window([tomogram])
        patches, corners = windowed_patches(tomogram, region, window, max_patches=2 * MAX_PATCHES)
        if len(patches) < 4 * FOLDS:  # each half of the floor needs 2 * FOLDS
            return None
        features = patch_features(patches)
        odd = slab_parity(corners[:, 0], slab) == 1
        try:
            floor = logistic_auc(features[~odd], features[odd])
        except SynthpackInputError:
            return None
        kept = np.linspace(0, len(features) - 1, min(len(features), MAX_PATCHES)).astype(np.int64)
        return cls(window, features[kept], floor)

    def auc(self, volume: np.ndarray, corners: np.ndarray) -> float | None:
        """The logistic AUC of `volume`'s patches at `corners` against the source's; None where too few.

        Parameters
        ----------
        volume : ndarray, shape (Z, Y, X)
            Intensities, in the source's units.
        corners : ndarray of int64, shape (N, 3)
            Patch corners (`~synthpack.measure.lattice.patch_corners` of `DEFAULT_PATCH`).
        """
        if len(corners) < 2 * FOLDS:
            return None
        try:
            return logistic_auc(self.features, patch_features(_windowed(volume, corners, self.window, DEFAULT_PATCH)))
        except SynthpackInputError:
            return None
