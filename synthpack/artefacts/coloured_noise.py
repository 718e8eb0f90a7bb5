"""Noise with a scanner's spectrum: coloured Gaussian noise, its own spectrum in grains and in pores.

A reconstructed CT scan's noise is not white: the reconstruction filter and the
detector shape its noise power spectrum (NPS), and grains and pores may differ.
`ColouredNoise` adds noise whose NPS, as
`synthpack.measure.spectrum.noise_power_spectrum` measures it (the in-slice patch
spectrum of the second difference across slices, rings ``k = 1, 2, ...`` at
``k / NPS_PATCH`` cycles per voxel), is ``pore_power`` in the pores and
``grain_power`` in the grains.

**Synthesis.** Each phase's noise is white Gaussian noise filtered in Fourier space
by ``sqrt(S(|f|))`` on a periodic cube of `TILE` voxels: an isotropic 3D spectrum
``S``, piecewise linear in ``|f|`` between knots at the ring frequencies (flat
below the first ring, falling to 0 one ring beyond the last: the in-slice rings
say little of the 3D corners of the spectrum, and a scanner's noise falls there). The knot values are the non-negative
least-squares solution of the linear map from ``S`` to the expected ring powers
(`ring_powers_of_spectrum`: the second difference's gain along z, then the
``NPS_PATCH``-voxel in-slice patches computed exactly from the in-slice
autocovariance, patch mean removed, as the measurement does), so the synthesized
noise has the asked ring powers in expectation. A voxel's noise is the cube's value
at its global index modulo `TILE`, so it does not depend on how the volume is cut
into blocks. The cube's white noise is drawn once per volume from the call's seed.

**Phases.** A voxel of intensity ``x`` (before the noise) is a fraction
``w = clip((x - pore_level) / (grain_level - pore_level), 0, 1)`` grain, and gets
``sqrt(1 - w) n_pore + sqrt(w) n_grain``: its variance is interpolated linearly
between the two phases' (CT noise variance depends on the intensity), and grain
and pore keep their own spectra. Either contrast sign works.

**On a torch device** the noise cubes are made on the CPU as above and moved to the
device once per volume; the periodic gather and the mixing by phase fraction run there.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import optimize

from .._shared.arrays import float32_value as _f32
from .._shared.arrays import periodic_indices, periodic_window
from ..measure.spectrum import NPS_PATCH, patch_lags, patch_ring_powers, slice_difference_gain
from ._base import BlockContext, Transform
from ._param import Param

if TYPE_CHECKING:
    import torch

    from .torch_blocks import DeviceVolume

__all__ = ["ColouredNoise", "TILE", "highpass_variance_of_spectrum", "ring_powers_of_spectrum", "spectrum_for_rings"]

#: Period (voxels) of the noise cubes along each axis.
TILE = 64


def _hats(n_knots: int, tile: int) -> np.ndarray:
    """Piecewise-linear basis in ``|f|`` on the ``tile^3`` FFT grid: knot ``j`` at ``(j + 1) / NPS_PATCH``.

    Returns float64, shape (n_knots, tile, tile, tile); the first is flat below its
    knot, the last falls to 0 one ring beyond it.
    """
    f = np.fft.fftfreq(tile)
    radius = np.sqrt(f[:, None, None] ** 2 + f[None, :, None] ** 2 + f[None, None, :] ** 2) * NPS_PATCH - 1.0
    radius = np.maximum(radius, 0.0)
    return np.stack([np.clip(1.0 - np.abs(radius - j), 0.0, 1.0) for j in range(n_knots)])


def ring_powers_of_spectrum(spectrum: np.ndarray, n_rings: int) -> np.ndarray:
    """Expected noise power spectrum (rings 1 to `n_rings`) of noise with 3D spectrum `spectrum`.

    What `~synthpack.measure.spectrum.noise_power_spectrum` measures: the in-slice
    patch NPS of the second difference across slices, whose gain
    (`~synthpack.measure.spectrum.slice_difference_gain`) weighs the spectrum along z
    (axis 0), from its in-slice autocovariance (`~synthpack.measure.spectrum.patch_ring_powers`).

    Parameters
    ----------
    spectrum : ndarray of float64, shape (T, T, T)
        ``S(f)`` on the FFT grid of a periodic cube, normalised so that ``mean(S)`` is the variance.
    n_rings : int

    Returns
    -------
    ndarray of float64, shape (n_rings,)
        Intensity units squared.
    """
    gain = slice_difference_gain(np.fft.fftfreq(spectrum.shape[0]))
    covariance = np.fft.ifft2((spectrum * gain[:, None, None]).mean(axis=0)).real  # in-slice, lag (0, 0) first
    lags = patch_lags()
    return patch_ring_powers(covariance[np.ix_(lags % covariance.shape[0], lags % covariance.shape[1])])[
        1 : n_rings + 1]


def highpass_variance_of_spectrum(spectrum: np.ndarray) -> float:
    """Variance that `~synthpack.measure.estimate_noise`'s 3D second difference sees in noise of `spectrum`.

    The filter ``[1, -2, 1]`` along every axis, divided by ``6^(3/2)``, has the gain
    ``prod_a (2 - 2 cos 2 pi f_a)^2 / 6^3`` (1 on average, so white noise keeps its variance).
    """
    f = np.fft.fftfreq(spectrum.shape[0])
    gain = (2.0 - 2.0 * np.cos(2.0 * np.pi * f)) ** 2 / 6.0
    return float(np.mean(spectrum * gain[:, None, None] * gain[None, :, None] * gain[None, None, :]))


@functools.lru_cache(maxsize=16)
def spectrum_for_rings(powers: tuple[float, ...], highpass: float | None = None, tile: int = TILE) -> np.ndarray:
    """The isotropic 3D spectrum whose expected ring powers are `powers` (see the module docstring).

    Parameters
    ----------
    powers : tuple of float
        Ring powers ``k = 1, 2, ...``, intensity units squared (>= 0).
    highpass : float, optional
        Also the variance `highpass_variance_of_spectrum` (intensity units squared), which
        pins the 3D high frequencies the in-slice rings say little of; the spectrum then
        gets one more knot, a ring beyond the last. Each equation's error is weighed
        relative to its target plus the largest target (so small targets are not
        forced at the others' cost).
    tile : int
        Side of the cube, voxels.

    Returns
    -------
    ndarray of float64, shape (tile, tile, tile)
        ``S(f) >= 0`` with ``mean(S)`` the noise variance; read-only.
    """
    n_rings = len(powers)
    hats = _hats(n_rings + (highpass is not None), tile)
    response = np.stack([ring_powers_of_spectrum(h, n_rings) for h in hats], axis=1)
    target = np.asarray(powers, dtype=np.float64)
    if highpass is not None:
        response = np.vstack([response, [highpass_variance_of_spectrum(h) for h in hats]])
        target = np.append(target, highpass)
    weight = 1.0 / (target + max(target.max(), np.finfo(float).tiny))
    knots, _ = optimize.nnls(response * weight[:, None], target * weight)
    spectrum = np.tensordot(knots, hats, axes=1)
    spectrum.flags.writeable = False
    return spectrum


@functools.lru_cache(maxsize=8)
def _field(powers: tuple[float, ...], highpass: float | None, tile: int, key: tuple[int, ...]) -> np.ndarray:
    """A periodic cube of noise of `spectrum_for_rings`, from the white noise of `key`; float32, read-only."""
    if not any(powers) and not highpass:
        field = np.zeros((tile,) * 3, dtype=np.float32)
    else:
        white = np.random.default_rng(list(key)).standard_normal((tile,) * 3)
        filter_ = np.sqrt(spectrum_for_rings(powers, highpass, tile))
        field = np.fft.ifftn(np.fft.fftn(white) * filter_).real.astype(np.float32)
    field.flags.writeable = False
    return field


def _square(value: float | None) -> float | None:
    return None if value is None else float(value) ** 2


class ColouredNoise(Transform):
    """Additive Gaussian noise with a given noise power spectrum in pores and grains (see the module docstring).

    Parameters
    ----------
    pore_power, grain_power : list of float
        Ring powers of the in-slice NPS (``k = 1, 2, ...`` at ``k / NPS_PATCH``
        cycles per voxel), intensity units squared, in the pore and in the grain phase.
    pore_level, grain_level : float
        Intensities of the two phases (either order): a voxel's phase fraction.
    pore_std, grain_std : float or None
        Also the noise level as `~synthpack.measure.estimate_noise` measures it (3D second
        differences), intensity units, in each phase: it pins the spectrum's 3D high
        frequencies (`spectrum_for_rings`). Default None.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "coloured_noise"
    params = (
        Param("pore_power", kind="floats", minimum=0.0, rangeable=False),
        Param("grain_power", kind="floats", minimum=0.0, rangeable=False),
        Param("pore_level", rangeable=False),
        Param("grain_level", rangeable=False),
        Param("pore_std", minimum=0.0, optional=True, rangeable=False),
        Param("grain_std", minimum=0.0, optional=True, rangeable=False),
    )

    def __init__(
        self, pore_power: Sequence[float], grain_power: Sequence[float], pore_level: float, grain_level: float,
        pore_std: float | None = None, grain_std: float | None = None, *, p: float = 1.0,
    ) -> None:
        super().__init__(pore_power=pore_power, grain_power=grain_power, pore_level=pore_level,
                         grain_level=grain_level, pore_std=pore_std, grain_std=grain_std, p=p)

    @staticmethod
    def _tiles(key: tuple[int, ...], **params: Any) -> tuple[np.ndarray, np.ndarray]:
        """The pore and the grain noise cubes of the white noise of `key`: float32, shape (TILE,) * 3, read-only."""
        pore, grain = (_field(tuple(params[f"{phase}_power"]), _square(params[f"{phase}_std"]), TILE, key + (k,))
                       for k, phase in enumerate(("pore", "grain")))
        return pore, grain

    @staticmethod
    def _call_key(call: np.random.SeedSequence) -> tuple[int, ...]:
        """The white noise's key of a block-by-block call: the same for every block."""
        return tuple(int(v) for v in call.generate_state(2))

    def _noise(self, block: np.ndarray, key: tuple[int, ...], origin: tuple[int, ...], **params: Any) -> np.ndarray:
        """The noise over `block` (whose first voxel is the global index `origin`), float32."""
        contrast = params["grain_level"] - params["pore_level"]
        grain = (block - np.float32(params["pore_level"])) / np.float32(contrast if contrast else 1.0)
        grain = np.clip(grain, 0.0, 1.0, out=grain)
        pore_field, grain_field = (periodic_window(tile, origin, block.shape) for tile in self._tiles(key, **params))
        pore = np.subtract(1.0, grain, dtype=np.float32)
        pore_field *= np.sqrt(pore, out=pore)
        grain_field *= np.sqrt(grain, out=grain)
        pore_field += grain_field
        return pore_field

    def _transform(self, image: np.ndarray, rng: np.random.Generator, **params: Any) -> np.ndarray:
        key = tuple(int(v) for v in rng.integers(0, 2**32, size=2))
        return image + self._noise(image, key, (0,) * image.ndim, **params)

    def _transform_block(self, block: np.ndarray, context: BlockContext, **params: Any) -> np.ndarray:
        noise = self._noise(block, self._call_key(context.call), context.origin, **params)
        noise += block
        return noise

    def _transform_block_torch(
        self, block: torch.Tensor, context: BlockContext, device: DeviceVolume, **params: Any
    ) -> torch.Tensor:
        key = self._call_key(context.call)
        tiles = device.once(("tiles", key), lambda: [device.put(t) for t in self._tiles(key, **params)])
        pore_field, grain_field = (_periodic_window(device, tile, context.origin, block.shape) for tile in tiles)
        contrast = params["grain_level"] - params["pore_level"]
        grain = ((block - _f32(params["pore_level"])) / _f32(contrast if contrast else 1.0)).clamp_(0.0, 1.0)
        pore = 1.0 - grain
        pore_field *= pore.sqrt_()
        grain_field *= grain.sqrt_()
        pore_field += grain_field
        return pore_field.add_(block)


def _periodic_window(device: DeviceVolume, tile: torch.Tensor, origin: Sequence[int],
                     shape: Sequence[int]) -> torch.Tensor:
    """`synthpack._shared.arrays.periodic_window` on the device: the same indices, gathered there."""
    out = tile
    for axis, index in enumerate(periodic_indices(origin, shape, tile.shape)):
        out = out.index_select(axis, device.put(index))
    return out
