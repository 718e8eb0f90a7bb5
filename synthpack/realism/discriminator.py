"""Classifier two-sample tests: can a model tell one set of patches from another?

Square in-slice patches of the same size are cut from both volumes' bulk regions
(`synthpack.measure.lattice`) and mapped through the same intensity window (the
source's 0.5 and 99.5 percentiles, as the YOLO export does) to [0, 1]. The larger
set is cut to an even subset of the smaller one's size, so the classes are balanced,
and the patches are split into stratified, shuffled folds (scikit-learn). Two
classifiers are trained on the same folds and scored by the area under the ROC
curve (AUC) of the held-out fold:

* **logistic**: a logistic regression (features standardised) on features that say
  how a patch looks, not where its grains are: the histogram of its intensities (16
  bins on [0, 1]: grey levels and contrast), the histogram of the absolute
  differences between neighbouring pixels (16 bins on [0, 0.5]: noise level and
  edge sharpness) and the log of its radially averaged power spectrum (mean
  removed: noise texture and blur; `synthpack.measure.patch_features`, which the
  calibration's guard measures too); the same regression on each of those three feature
  groups alone (`~synthpack.measure.patch_features.FEATURE_GROUPS`) says which of them tells
  the sets apart;
* **cnn**: a small convolutional network trained from scratch on the patches
  themselves (`synthpack.realism.cnn`), which learns its own features.

An AUC of 0.5 means a classifier does no better than chance: the patches are
indistinguishable to it. 1 means it tells every patch of one set from every patch of
the other. Each is a lower bound on how distinguishable the sets are: a stronger
model might still tell them apart. Neither cares which set is brighter: both learn
the sign of any difference.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from .._shared.schema import non_negative, positive, setting
from ..errors import SynthpackInputError
from ..measure.patch_features import (DEFAULT_PATCH, FEATURE_GROUPS, FOLDS, MAX_PATCHES, balanced_folds,
                                      logistic_fold_auc, patch_features, windowed_patches)
from .region import Specimen

logger = logging.getLogger(__name__)

__all__ = ["ClassifierTest", "CnnConfig", "DEFAULT_PATCH", "MAX_PATCHES", "check_patch", "classifier_test",
           "patch_features", "specimen_patches"]


def check_patch(patch: int, shape: tuple[int, ...] | None = None, what: str = "the volume") -> None:
    """Refuse a patch side that is not a whole number >= 2, or (given `shape`) wider than `what`'s slices.

    Parameters
    ----------
    patch : int
        Patch side, voxels.
    shape : tuple of 3 int, optional
        ``(Z, Y, X)`` of a volume the patches are cut from (in its slices, axis 0).
    what : str
        The volume, for the message.

    Raises
    ------
    SynthpackInputError
        If `patch` is not an integer of at least 2, or does not fit a slice of `shape`.
    """
    if isinstance(patch, bool) or not isinstance(patch, (int, np.integer)) or patch < 2:
        raise SynthpackInputError(f"the classifier patch side (--patch) must be a whole number of voxels >= 2 "
                                  f"(one voxel has no texture to judge), not {patch!r}")
    if shape is not None and patch > min(shape[1:]):
        raise SynthpackInputError(
            f"a classifier patch of {patch} voxels (--patch) does not fit {what}'s {shape[1]}x{shape[2]} slices: "
            f"give a patch of at most {min(shape[1:])} voxels (default {DEFAULT_PATCH})"
        )


def specimen_patches(
    specimen: Specimen, window: tuple[float, float], *, size: int = DEFAULT_PATCH, max_patches: int = MAX_PATCHES
) -> tuple[np.ndarray, np.ndarray]:
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
    patches : ndarray of float32, shape (N, size, size)
    corners : ndarray of int64, shape (N, 3)
        ``(z, y0, x0)`` of each patch's first voxel, in slice order.

    Raises
    ------
    SynthpackInputError
        If `size` is not a whole number >= 2, or no patch of it lies wholly in the bulk region.
    """
    check_patch(size, specimen.tomogram.shape, specimen.name)
    patches, corners = windowed_patches(specimen.tomogram, specimen.region, window, size=size, max_patches=max_patches)
    if not len(corners):
        raise SynthpackInputError(
            f"no {size}x{size} classifier patch lies wholly inside the bulk region of {specimen.name}: "
            "give a smaller patch (--patch)"
        )
    return patches, corners


@dataclass(frozen=True)
class CnnConfig:
    """Training settings of the CNN discriminator (`synthpack.realism.cnn`).

    Attributes
    ----------
    epochs : int
        Passes over each training fold.
    batch_size : int
        Patches per minibatch.
    learning_rate : float
        Peak Adam step size of the one-cycle schedule.
    weight_decay : float
        L2 penalty on the weights (Adam's ``weight_decay``).
    width : int
        Channels of the first convolutions (the last two have twice as many).
    threads : int
        Torch threads while training; 1 makes the scores independent of the machine (`synthpack.realism.cnn`).
    """

    epochs: int = setting(20, positive, "passes over each training fold")
    batch_size: int = setting(64, positive, "patches per minibatch")
    learning_rate: float = setting(3e-3, positive, "peak Adam step size of the one-cycle schedule")
    weight_decay: float = setting(1e-4, non_negative, "L2 penalty on the weights")
    width: int = setting(16, positive, "channels of the first convolutions")
    threads: int = setting(1, positive, "torch threads while training (1: scores independent of the machine)")


@dataclass
class ClassifierTest:
    """The result of one classifier two-sample test (see the module docstring).

    Attributes
    ----------
    patches : ndarray of float32, shape (2n, S, S)
        The balanced patches: the n of the first set (target 0), then the n of the second (target 1).
    target : ndarray of int64, shape (2n,)
    folds : list of (ndarray, ndarray)
        ``(train, test)`` indices of each fold, the same for every classifier.
    fold_auc : dict of str to ndarray of float64, shape (k,)
        Per classifier (``"logistic"``, ``"cnn"``), the AUC of each held-out fold.
    seconds : dict of str to float
        Per classifier, the wall time of its cross-validation.
    cnn_scores : ndarray of float64, shape (2n,), or None
        The CNN's out-of-fold logit of "second set" for every patch; None without the CNN.
    feature_auc : dict of str to float
        Per feature group (`~synthpack.measure.patch_features.FEATURE_GROUPS`), the mean
        held-out AUC of the logistic regression on that group alone, on the same folds.
    """

    patches: np.ndarray
    target: np.ndarray
    folds: list[tuple[np.ndarray, np.ndarray]]
    fold_auc: dict[str, np.ndarray] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    cnn_scores: np.ndarray | None = None
    feature_auc: dict[str, float] = field(default_factory=dict)

    @property
    def n_per_class(self) -> int:
        """Patches in each set."""
        return len(self.target) // 2

    def auc(self, classifier: str) -> float | None:
        """Mean AUC over the folds of `classifier`, or None if it was not run."""
        return float(self.fold_auc[classifier].mean()) if classifier in self.fold_auc else None

    def record(self, classifier: str, fold_auc: np.ndarray, seconds: float) -> None:
        """Keep a classifier's held-out AUC per fold and the seconds its cross-validation took."""
        self.fold_auc[classifier] = np.asarray(fold_auc, dtype=np.float64)
        self.seconds[classifier] = seconds
        logger.info("%s AUC %.3f +- %.3f (%d patches per class, %.1f s)", classifier, self.fold_auc[classifier].mean(),
                    self.fold_auc[classifier].std(), self.n_per_class, seconds)

    def summary(self, floor: ClassifierTest | None = None) -> dict:
        """JSON-able figures: patches per class, folds, per classifier its AUC, spread and seconds, and under
        ``logistic_features`` the logistic AUC of each feature group alone (`feature_auc`).

        Parameters
        ----------
        floor : ClassifierTest, optional
            The source against itself (`synthpack.realism.floor`): each classifier then
            also gets ``margin``, its AUC minus the floor's.
        """
        result: dict = {"n_per_class": self.n_per_class, "folds": len(self.folds)}
        for name, aucs in self.fold_auc.items():
            result[name] = {"auc": float(aucs.mean()), "auc_std": float(aucs.std()),
                            "seconds": self.seconds[name]}
            floor_auc = floor.auc(name) if floor is not None else None
            if floor_auc is not None:
                result[name]["margin"] = float(aucs.mean()) - floor_auc
        if self.feature_auc:
            result["logistic_features"] = dict(self.feature_auc)
        return result


def classifier_test(
    first: np.ndarray,
    second: np.ndarray,
    *,
    folds: int = FOLDS,
    seed: int = 0,
    cnn: CnnConfig | None = None,
    feature_groups: bool = False,
) -> ClassifierTest:
    """Cross-validated AUCs of the classifiers telling `first` from `second` patches.

    Both sets are cut to the same size (an even subset of the larger one) so that
    the classes are balanced; both classifiers use the same folds.

    Parameters
    ----------
    first, second : ndarray, shape (N, S, S) and (M, S, S)
        Windowed patches (`specimen_patches`), the same S: e.g. real and synthetic.
    folds : int
        Stratified cross-validation folds (>= 2).
    seed : int
        Seed of the fold shuffling and of the CNN.
    cnn : CnnConfig, optional
        Also train the CNN with these settings; None = the logistic regression only.
    feature_groups : bool
        Also fit the logistic regression on each feature group alone (`ClassifierTest.feature_auc`).

    Returns
    -------
    ClassifierTest

    Raises
    ------
    SynthpackInputError
        If the patch sizes differ or a set has fewer than ``2 * folds`` patches.
    """
    if first.shape[1:] != second.shape[1:]:
        raise SynthpackInputError(f"patches differ in size: {first.shape[1:]} and {second.shape[1:]}")
    take, target, splits = balanced_folds(len(first), len(second), folds=folds, seed=seed)
    patches = np.concatenate([first[take[0]], second[take[1]]])
    test = ClassifierTest(patches, target, splits)
    start = time.perf_counter()
    features = patch_features(patches)
    test.record("logistic", logistic_fold_auc(features, target, splits), time.perf_counter() - start)
    if feature_groups:
        test.feature_auc = {group: float(logistic_fold_auc(features[:, columns], target, splits).mean())
                            for group, columns in FEATURE_GROUPS.items()}
    if cnn is not None:
        from sklearn.metrics import roc_auc_score

        from .cnn import out_of_fold_scores

        start = time.perf_counter()
        test.cnn_scores = out_of_fold_scores(patches, target, splits, config=cnn, seed=seed)
        held_out_auc = [roc_auc_score(target[held], test.cnn_scores[held]) for _, held in splits]
        test.record("cnn", np.array(held_out_auc), time.perf_counter() - start)
    return test
