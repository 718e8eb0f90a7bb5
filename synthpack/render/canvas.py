"""One chunk of the output as grains are drawn onto it: labels by claim, intensities pasted or composited.

Written once against the array module (``xp``: numpy or torch), so the NumPy render
(`~synthpack.render.numpy_render.render_chunk`) and the torch one
(`~synthpack.render.torch_render.TorchRenderer`) draw with the same code; they differ
only in which voxels of a grain's box they visit and in how they interpolate its crop
(a `Sampler`). On a NumPy canvas a grain can instead be drawn in one compiled pass over
its box (`Canvas.draw_box`, `synthpack.render.kernel`), with the same arithmetic.

Each grain is drawn from its smooth surface (`synthpack.render.surface`): the signed
distance ``s`` of every voxel from it, resampled linearly from the crop's and scaled to
output voxels (positive inside). Claims: placement ``i`` labels ``i + 1`` the voxels
where ``s > 0``; a voxel claimed by two goes to the larger ``s``, the grain it is deeper
in (the earlier placement on a tie), a rule that does not depend on the chunking.
Intensities: where a grain wins a voxel its resampled crop is pasted (whole voxels), or
every grain is composited over the background by its occupancy, from the same ``s``
(`synthpack.render.partial_volume`),

    out = (1 - min(O, 1)) background + V / max(O, 1),   O = sum_i o_i,   V = sum_i o_i g_i.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from .crops import RenderCrop
from .kernel import draw_box
from .partial_volume import FAR, PAD, PartialVolume

__all__ = ["Canvas", "Sampler"]


class Sampler(Protocol):
    """Interpolates a crop at the crop coordinates ``mapped + shift`` (per axis), as `scipy.ndimage.map_coordinates`.

    Parameters
    ----------
    volume : array
        A crop array of `RenderCrop` (its intensity or distance).
    mapped : array of float64, shape (3, K)
        `~synthpack.render.poses.mapped` of the voxels.
    shift : ndarray of float64, shape (3,)
        Added to `mapped` per axis: the affine offset (plus the crop's padding).
    order : int
        Spline order.
    cval : float or None
        Value beyond the crop (SciPy's ``"constant"`` mode); None: the nearest crop voxel's (``"nearest"``).

    Returns
    -------
    array of float32, shape (K,)
    """

    def __call__(self, volume: Any, mapped: Any, shift: np.ndarray, order: int, cval: float | None) -> Any: ...


class Canvas:
    """One chunk's tomogram and labels as grains are drawn onto its background, in NumPy or torch.

    Parameters
    ----------
    background : array of float32, shape (z, y, x), C-contiguous
        The chunk's background (`~synthpack.render.background.background_values`); drawn over in place.
    sample : Sampler
        Interpolates the grains' crops.
    xp : module
        numpy or torch: the array module of `background`, `sample`'s values and the voxel indices.
    order : int
        Spline order of the intensities (signed distances are interpolated linearly).
    partial_volume : PartialVolume, optional
        Composite grains by their occupancy of each voxel; None: paste whole voxels (a hard step).

    Attributes
    ----------
    tomogram : array of float32, shape (z, y, x)
        `background`, with the grains drawn once `finish` is called.
    labels : array of int32, shape (z, y, x)
    contested : int
        Voxels claimed by more than one placement.
    """

    def __init__(
        self, background: Any, sample: Sampler, xp: Any, order: int = 1, partial_volume: PartialVolume | None = None,
    ) -> None:
        self.tomogram = background
        self.labels = xp.zeros_like(background, dtype=xp.int32)
        self.contested = 0
        self._claim = xp.zeros_like(background)
        self._sample, self._xp, self._order, self._partial_volume = sample, xp, order, partial_volume
        self._occupancy = self._value = None
        if partial_volume is not None:
            self._occupancy, self._value = xp.zeros_like(background), xp.zeros_like(background)

    def draw(self, label: int, index: Any, mapped: Any, offset: np.ndarray, crop: RenderCrop, matrix: np.ndarray) -> Any:
        """Draw one grain over the chunk's voxels `index`.

        Parameters
        ----------
        label : int
            The grain's label (its placement + 1); grains are drawn in placement order.
        index : array of int, shape (K,)
            Flat indices into the chunk (no repeats) of the voxels of the grain's box to draw.
        mapped : array of float64, shape (3, K)
            `~synthpack.render.poses.mapped` of those voxels (their indices in the box).
        offset : ndarray of float, shape (3,)
            Crop index of the box's first voxel (`~synthpack.render.poses.grain_boxes`).
        crop : RenderCrop
            The grain's crop, in the canvas's array module.
        matrix : ndarray of float, shape (3, 3)
            The grain's `~synthpack.render.poses.PoseMaps` matrix.

        Returns
        -------
        array of float32, shape (K,)
            The signed distance of the voxels from the grain's smooth surface, output voxels
            (its claims are where it is positive).
        """
        distance = self._sample(crop.distance, mapped, offset + PAD, 1, FAR) * float(_scale(matrix))
        wins = self._claim_voxels(label, index, distance)
        if self._partial_volume is None:
            self.tomogram.reshape(-1)[index[wins]] = self._sample(crop.intensity, mapped[:, wins],
                                                                  self._intensity_shift(offset), self._order, None)
        else:
            self._add(index, mapped, self._intensity_shift(offset), crop, distance)
        return distance

    def draw_box(
        self, label: int, corner: np.ndarray, shape: np.ndarray, offset: np.ndarray, crop: RenderCrop,
        matrix: np.ndarray, intensities: tuple[np.ndarray, int],
    ) -> None:
        """Draw one grain over a box of the chunk in one compiled pass, as `draw` draws it (NumPy canvases only).

        Visits every voxel of the box once (`~synthpack.render.kernel.draw_box`): the voxels
        outside the crop's support are left alone, the others drawn with `draw`'s arithmetic.

        Parameters
        ----------
        label : int
            The grain's label (its placement + 1); grains are drawn in placement order.
        corner, shape : ndarray of int, shape (3,)
            The box's first voxel in the chunk, and its shape (voxels).
        offset : ndarray of float, shape (3,)
            Crop index of the box's first voxel (`~synthpack.render.poses.grain_boxes`).
        crop : RenderCrop
            The grain's crop, with its support.
        matrix : ndarray of float, shape (3, 3)
            The grain's `~synthpack.render.poses.PoseMaps` matrix.
        intensities : (ndarray, int)
            `~synthpack.render.kernel.spline_coefficients` of ``crop.intensity`` for the canvas's order.
        """
        sums = () if self._partial_volume is None else (self._occupancy, self._value)
        self.contested += draw_box(
            label, corner, shape, matrix, offset + PAD, self._intensity_shift(offset), crop.support, crop.distance,
            FAR, _scale(matrix), intensities, self._order,
            None if self._partial_volume is None else self._partial_volume.level,
            (self.labels, self._claim, self.tomogram, *sums),
        )

    def finish(self) -> None:
        """Composite the grains onto the background (the partial volume's ``(1 - O) b + V``, ``V / O`` where ``O > 1``)."""
        if self._partial_volume is not None:
            self.tomogram *= 1.0 - self._occupancy.clip(max=1.0)
            self.tomogram += self._value * (1.0 / self._occupancy.clip(min=1.0))

    def _intensity_shift(self, offset: np.ndarray) -> np.ndarray:
        """Crop coordinates of a box's first voxel in the intensities: `offset`, plus the padding of prepared ones."""
        return offset if self._partial_volume is None else offset + PAD

    def _claim_voxels(self, label: int, index: Any, distance: Any) -> Any:
        """Give `label` the voxels `index` where `distance` is positive and above every earlier claim; which (bool, (K,))."""
        inside = distance > 0
        held = self._claim.reshape(-1)[index]  # 0 where unclaimed
        self.contested += int(self._xp.count_nonzero(inside & (held > 0)))
        wins = inside & (distance > held)
        won = index[wins]
        self.labels.reshape(-1)[won] = label
        self._claim.reshape(-1)[won] = distance[wins]
        return wins

    def _add(self, index: Any, mapped: Any, shift: np.ndarray, crop: RenderCrop, distance: Any) -> None:
        """Add one grain's occupancy ``o`` (of its signed `distance`, output voxels) and ``o g`` at the voxels `index`
        (crop coordinates ``mapped + shift``)."""
        occupancy = self._partial_volume.occupancy(distance)
        some = occupancy > 0
        if not self._xp.count_nonzero(some):
            return
        occupancy, index = occupancy[some], index[some]
        self._occupancy.reshape(-1)[index] += occupancy
        self._value.reshape(-1)[index] += occupancy * self._sample(crop.intensity, mapped[:, some], shift,
                                                                   self._order, None)


def _scale(matrix: np.ndarray) -> np.float32:
    """Output voxels per crop voxel of a grain drawn with the pose `matrix` (float32: the distances' factor)."""
    return np.float32(abs(np.linalg.det(matrix)) ** (-1.0 / 3.0))
