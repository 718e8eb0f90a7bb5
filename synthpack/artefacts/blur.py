"""Blur: isotropic Gaussian (detector and focal-spot blur) and linear motion blur.

Both work on a volume (Z, Y, X) or a slice (H, W) of float32 intensities, with
lengths in voxels. Borders are handled by mirroring (``mode="reflect"``), so a
uniform image stays uniform.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from ._base import Transform
from ._param import Param, Range

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
