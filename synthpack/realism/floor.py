"""The floor of the classifier tests: the source scan against itself.

Before any pack is judged, each classifier of `synthpack.realism.discriminator` is
asked to tell two sets of patches of the *source* apart: those from the even and
those from the odd slabs of `slab` slices along z (the slice axis). Both sets are
the same material, scanned and reconstructed in the same way, so whatever AUC the
classifiers reach here comes from the scan's own variation: drift along z (beam
intensity, sample settling, ring and cupping changes), grains that differ from
place to place, and the spread of the cross-validation itself. A pack cannot be
expected to look closer to the source than the source looks to itself, so that
AUC is the floor; a pack's *margin* is its AUC minus the floor's.

Why interleaved slabs and not two halves: a real scan drifts along z, and two
plain halves pick the drift up as a difference (on a 100^3 neutron scan of
concrete the logistic AUC is 0.79 for two halves, 0.64 for interleaved slabs of
10 slices). Why not single slices: neighbouring slices show the same grains, so
patches on either side of a slab boundary are nearly the same picture; thin slabs
put many such pairs in opposite sets and press the floor towards 0.5 for reasons
that have nothing to do with realism (the same scan gives 0.58 with 5-slice slabs
and 0.75 with 20). The default, `DEFAULT_SLAB` = 10 slices, is about one to two
grain diameters in the scans synthpack is used on, so most grains lie in one
slab, and short against the drift. Choose a slab of about one grain diameter
(the report gives the source's median diameter) for grains much larger or smaller.
"""

from __future__ import annotations

import numpy as np

from ..errors import SynthpackInputError
from ..measure.patch_features import DEFAULT_SLAB, FOLDS, slab_parity
from .discriminator import ClassifierTest, CnnConfig, classifier_test

__all__ = ["DEFAULT_SLAB", "check_slab", "floor_test", "slab_parity"]


def check_slab(slab: int) -> None:
    """Refuse a slab thickness below one slice.

    Raises
    ------
    SynthpackInputError
        If `slab` is not an integer of at least 1.
    """
    if isinstance(slab, bool) or not isinstance(slab, (int, np.integer)) or slab < 1:
        raise SynthpackInputError(f"the floor's slab thickness must be a whole number of slices >= 1, not {slab!r}")


def floor_test(
    patches: np.ndarray,
    corners: np.ndarray,
    *,
    slab: int = DEFAULT_SLAB,
    folds: int = FOLDS,
    seed: int = 0,
    cnn: CnnConfig | None = None,
) -> ClassifierTest:
    """The classifier test of the source's even slabs against its odd slabs.

    Parameters
    ----------
    patches : ndarray, shape (N, S, S)
        The source's windowed patches (`~synthpack.realism.discriminator.specimen_patches`).
    corners : ndarray of int, shape (N, 3)
        Their corners; column 0 is the slice.
    slab : int
        Slab thickness, slices (>= 1; see the module docstring).
    folds, seed, cnn
        As for `~synthpack.realism.discriminator.classifier_test`.

    Returns
    -------
    ClassifierTest
        Set 0 = the even slabs, set 1 = the odd slabs.

    Raises
    ------
    SynthpackInputError
        If `slab` is below 1, or the patches do not reach into both even and odd slabs.
    """
    check_slab(slab)
    odd = slab_parity(corners[:, 0], slab) == 1
    if odd.all() or not odd.any():
        raise SynthpackInputError(
            f"the source's patches lie in slabs of one parity only (slab {slab} slices, patches in slices "
            f"{int(corners[:, 0].min())}-{int(corners[:, 0].max())}): use a thinner slab"
        )
    return classifier_test(patches[~odd], patches[odd], folds=folds, seed=seed, cnn=cnn)
