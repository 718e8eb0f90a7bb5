"""Blur: isotropic Gaussian (detector and focal-spot blur) and linear motion blur.

Both work on a volume (Z, Y, X) or a slice (H, W) of float32 intensities, with
lengths in voxels. Borders are handled by mirroring (``mode="reflect"``), so a
uniform image stays uniform.

Their torch block steps apply this module's kernels (`gaussian_kernel`,
`line_kernel`) to the block mirrored beyond its edges as SciPy's ``"reflect"``
(NumPy's ``"symmetric"``) mirrors it, as weighted sums of shifted copies (the
Gaussian separably, axis after axis) in float64, rounded to float32 after each axis
as SciPy rounds: plain multiply-adds, so no reduced-precision (TF32) convolution can
enter, and the values are SciPy's but for the order of the sum. (A float32 sum
differs in the last bits, which the coloured noise's ``sqrt`` of the grain fraction
amplifies near the pore level to about 1e-5 of the intensity range.)
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from ._base import BlockContext, Transform
from ._param import Param, Range

if TYPE_CHECKING:
    import torch

    from .torch_blocks import DeviceVolume

__all__ = ["GaussianBlur", "MotionBlur", "gaussian_kernel", "line_kernel"]

#: The Gaussian kernel is cut at this many standard deviations (SciPy's default).
_TRUNCATE = 4.0


def _radius(sigma: float) -> int:
    """Half the side of the Gaussian kernel of `sigma`, as `scipy.ndimage.gaussian_filter` cuts it."""
    return int(_TRUNCATE * sigma + 0.5)


def gaussian_kernel(sigma: float) -> np.ndarray:
    """The 1D kernel `GaussianBlur` applies along each axis: SciPy's ``gaussian_filter1d`` kernel.

    Parameters
    ----------
    sigma : float
        Standard deviation in voxels (> 0).

    Returns
    -------
    ndarray of float64, shape (2 r + 1,)
        ``exp(-x^2 / 2 sigma^2)`` at ``x = -r ... r``, ``r = int(4 sigma + 0.5)``, normalised to sum 1.
    """
    radius = _radius(sigma)
    x = np.arange(-radius, radius + 1)
    weights = np.exp(-0.5 / (sigma * sigma) * x**2)
    return weights / weights.sum()


def line_kernel(length: float, angle: float) -> np.ndarray:
    """A normalised 2D kernel of a straight segment: the point-spread of linear motion.

    Parameters
    ----------
    length : float
        Segment length in pixels (>= 0); 0 gives the identity kernel ``[[1]]``.
    angle : float
        Direction in degrees, from the +x axis (axis 1 of the slice) towards +y
        (axis 0); 0 is a horizontal streak, 90 a vertical one.

    Returns
    -------
    ndarray of float64, shape (k, k), k odd
        Non-negative weights summing to 1, symmetric about the centre. The segment
        is sampled at 4 points per pixel and each point spread bilinearly onto the
        grid, so lengths and angles need not be whole numbers.
    """
    half = int(math.ceil(length / 2.0))
    size = 2 * half + 1
    kernel = np.zeros((size, size), dtype=np.float64)
    n_points = max(1, int(math.ceil(4 * length))) + 1
    t = np.linspace(-length / 2.0, length / 2.0, n_points)
    theta = math.radians(angle)
    y = half + t * math.sin(theta)
    x = half + t * math.cos(theta)
    y0 = np.clip(np.floor(y).astype(int), 0, size - 1)
    x0 = np.clip(np.floor(x).astype(int), 0, size - 1)
    y1 = np.minimum(y0 + 1, size - 1)
    x1 = np.minimum(x0 + 1, size - 1)
    fy = y - y0
    fx = x - x0
    for yy, xx, w in (
        (y0, x0, (1 - fy) * (1 - fx)),
        (y0, x1, (1 - fy) * fx),
        (y1, x0, fy * (1 - fx)),
        (y1, x1, fy * fx),
    ):
        np.add.at(kernel, (yy, xx), w)
    return kernel / kernel.sum()


def _mirrored(device: DeviceVolume, block: torch.Tensor, halo: Iterable[int]) -> torch.Tensor:
    """`block` extended by `halo` voxels on both sides of each axis, mirrored (NumPy ``"symmetric"``)."""
    for axis, h in enumerate(halo):
        if h:
            n = block.shape[axis]
            index = np.arange(-h, n + h) % (2 * n)
            index = np.where(index < n, index, 2 * n - 1 - index)
            block = block.index_select(axis, device.put(index))
    return block


def _correlate(padded: torch.Tensor, kernel: np.ndarray) -> torch.Tensor:
    """The "valid" correlation of `padded` with `kernel` (same number of axes): ``sum_k kernel[k] padded[k:k+n]``.

    Summed in float64 over the non-zero weights and rounded to float32 once, as SciPy's
    filters sum and round (so the result is theirs but for the order of the sum). The
    output is smaller than `padded` by ``kernel.shape - 1`` on each axis.
    """
    import torch

    shape = [int(n) - k + 1 for n, k in zip(padded.shape, kernel.shape)]
    wide = padded.to(torch.float64)
    out = torch.zeros(shape, dtype=torch.float64, device=padded.device)
    for offset in zip(*np.nonzero(kernel)):
        out.add_(wide[tuple(slice(int(o), int(o) + n) for o, n in zip(offset, shape))], alpha=float(kernel[offset]))
    return out.to(torch.float32)


class GaussianBlur(Transform):
    """Isotropic Gaussian blur: the point-spread of the detector and focal spot.

    Applied over all axes of the input: in 3D for a volume, in-plane for a 2D
    slice. Blurring white noise of variance ``v`` leaves a variance of about
    ``v / (8 pi^1.5 sigma^3)`` in 3D and ``v / (4 pi sigma^2)`` in 2D (sigma >~ 1).

    Parameters
    ----------
    sigma : float or (float, float)
        Standard deviation of the Gaussian in voxels (>= 0; 0 leaves the image
        unchanged); a ``(min, max)`` pair is drawn uniformly per call. Default 0.7.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "gaussian_blur"
    params = (Param("sigma", minimum=0.0),)
    locality = "neighbourhood"

    def __init__(self, sigma: Range = 0.7, *, p: float = 1.0) -> None:
        super().__init__(sigma=sigma, p=p)

    def halo(self, *, sigma: float) -> tuple[int, int, int]:
        """The kernel radius of `scipy.ndimage.gaussian_filter`, ``int(4 sigma + 0.5)``, on every axis."""
        radius = _radius(sigma)
        return (radius, radius, radius)

    def _transform(self, image: np.ndarray, rng: np.random.Generator, *, sigma: float) -> np.ndarray:
        if sigma == 0:
            return image.copy()
        return ndimage.gaussian_filter(image, sigma, output=np.float32, mode="reflect", truncate=_TRUNCATE)

    def _transform_block_torch(
        self, block: torch.Tensor, context: BlockContext, device: DeviceVolume, *, sigma: float
    ) -> torch.Tensor:
        if sigma == 0:
            return block.clone()
        kernel = gaussian_kernel(sigma)
        out = _mirrored(device, block, (kernel.size // 2,) * 3)
        for axis in range(3):
            out = _correlate(out, kernel.reshape([-1 if a == axis else 1 for a in range(3)]))
        return out


class MotionBlur(Transform):
    """Linear motion blur within each slice: convolution with a line segment.

    Stands in for the sample or stage moving during the exposure. The segment
    (see `line_kernel`) lies in the slice plane (Y, X) at `angle`; for a volume
    every slice gets the same kernel (no blur along z).

    Parameters
    ----------
    length : float or (float, float)
        Length of the streak in voxels (>= 0); a ``(min, max)`` pair is drawn
        uniformly per call. Default 3.
    angle : float or (float, float)
        Direction in degrees from +x towards +y; drawn uniformly per call from a
        ``(min, max)`` pair. Default (0, 180): any direction.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "motion_blur"
    params = (Param("length", minimum=0.0), Param("angle"))
    locality = "neighbourhood"

    def __init__(self, length: Range = 3.0, angle: Range = (0.0, 180.0), *, p: float = 1.0) -> None:
        super().__init__(length=length, angle=angle, p=p)

    def halo(self, *, length: float, angle: float) -> tuple[int, int, int]:
        """Half the line kernel's side in the slice plane, nothing along z."""
        half = line_kernel(length, angle).shape[0] // 2
        return (0, half, half)

    def _transform(
        self, image: np.ndarray, rng: np.random.Generator, *, length: float, angle: float
    ) -> np.ndarray:
        kernel = line_kernel(length, angle).astype(np.float32)
        if kernel.size == 1:
            return image.copy()
        if image.ndim == 3:
            kernel = kernel[None]
        return ndimage.convolve(image, kernel, output=np.float32, mode="reflect")

    def _transform_block_torch(
        self, block: torch.Tensor, context: BlockContext, device: DeviceVolume, *, length: float, angle: float
    ) -> torch.Tensor:
        kernel = line_kernel(length, angle).astype(np.float32)  # the weights `_transform` gives SciPy
        if kernel.size == 1:
            return block.clone()
        half = kernel.shape[0] // 2
        # SciPy's convolve is a correlation with the flipped kernel
        return _correlate(_mirrored(device, block, (0, half, half)), np.flip(kernel)[None])
