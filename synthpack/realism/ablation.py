"""Where the classifiers see a pack's difference: the same patches with a phase made flat.

A classifier AUC says how well a pack can be told from its source, not where the
difference lies. The ablation asks again with parts of every patch taken away, the same
way in the source and in the pack, so that what is left is all the classifiers can use:

==============  ==========================================================  ===========================
ablation        every patch, in the source and in the pack                  what the classifiers see
==============  ==========================================================  ===========================
grains flat     its grains set to the source's grain level                  the pores, edges, geometry
pores flat      its pores set to the source's pore level                    the grains, edges, geometry
edges only      both, but for the voxels at the boundary                    the edges, the geometry
labels only     both: the labels drawn in the two levels                    the geometry
==============  ==========================================================  ===========================

The phases are cut by a soft matte, not at the label boundary: ``m``, the grain mask
(label > 0) smoothed with a Gaussian of `SOFTNESS` voxels, so that a voxel becomes
``m G + (1 - m) v`` with grains made flat (``G`` the grain level, ``v`` its intensity),
``m v + (1 - m) P`` with pores made flat and ``m G + (1 - m) P`` for the labels alone;
edges only keeps ``v`` with the weight ``4 m (1 - m)`` (1 on the boundary) over the labels
alone. A hard cut would draw every label's outline as a sharp edge, and a watershed's
outlines are jagged where a pack's are smooth: the classifiers would read the labelling,
not the image. The voxels on the boundary belong to both phases by halves, so a phase made
flat still shows a little of its texture there.

Read each row against the pack's AUC as it is and against ``labels only``: where making
the pores flat brings an AUC down to ``labels only``, what tells the pack apart is in its
pore phase (a texture, a level); where neither phase made flat brings it down but
``edges only`` keeps it, it is at the boundaries (the edge's profile, the voxels next to
the grains); where ``labels only`` is itself far above the floor, the grains' shapes,
sizes or arrangement already differ. On the real neutron CT of concrete
(docs/realism-concrete.md) the CNN stays at 0.994-0.996 with either phase flat and with
the edges only, and falls to 0.751 with the labels only: the difference lies at the
boundaries. On the sand micro-CT (docs/realism-sand.md) each part alone takes it from 0.997
to 0.82-0.91, and the labels alone give 0.766: most of it the way the labels are drawn (the
scan's by a segmentation of its blurred image, which joins grains closer than the blur), 0.61 for a
pack with ``reconstruct.labels: segmented`` (`synthpack.render.segmented_labels`).

The patches are the ones the classifier test cuts (same corners and intensity window),
with the flat levels taken from the source (its appearance's interior medians), so
nothing is drawn at random and the ablation adds no noise of its own.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..measure.lattice import take_patches

__all__ = ["ABLATIONS", "SOFTNESS", "ablated_patches"]

#: Standard deviation (voxels) of the Gaussian that smooths the grain mask into the matte.
SOFTNESS = 1.0

#: The ablations, each the phases it makes flat (see the module docstring).
ABLATIONS: dict[str, tuple[str, ...]] = {
    "grains flat": ("grains",),
    "pores flat": ("pores",),
    "edges only": ("grains", "pores", "edges"),
    "labels only": ("grains", "pores"),
}


def ablated_patches(
    patches: np.ndarray,
    labels: np.ndarray,
    corners: np.ndarray,
    levels: dict[str, float],
    window: tuple[float, float],
) -> dict[str, np.ndarray]:
    """Each ablation of windowed classifier patches (see the module docstring).

    Parameters
    ----------
    patches : ndarray of float32, shape (N, S, S)
        Windowed patches (`~synthpack.realism.discriminator.specimen_patches`).
    labels : ndarray of int, shape (Z, Y, X)
        The specimen's labels (0 = pore).
    corners : ndarray of int64, shape (N, 3)
        The patches' ``(z, y0, x0)`` corners.
    levels : dict
        ``{"grains": float, "pores": float}``: the flat intensities (the source's phase
        levels), in the volume's units.
    window : (float, float)
        Intensities ``lo`` and ``hi`` mapped to 0 and 1, as the patches were.

    Returns
    -------
    dict of str to ndarray of float32, shape (N, S, S)
        One entry per `ABLATIONS` key.
    """
    matte = take_patches(ndimage.gaussian_filter((labels > 0).astype(np.float32), SOFTNESS), corners,
                         patches.shape[1])
    lo, hi = window
    flat = {phase: np.float32(np.clip((level - lo) / (hi - lo), 0.0, 1.0)) for phase, level in levels.items()}
    result = {}
    for name, phases in ABLATIONS.items():
        grains = flat["grains"] if "grains" in phases else patches
        pores = flat["pores"] if "pores" in phases else patches
        ablated = matte * grains + (1 - matte) * pores
        if "edges" in phases:
            ablated += 4 * matte * (1 - matte) * (patches - ablated)
        result[name] = ablated.astype(np.float32)
    return result
