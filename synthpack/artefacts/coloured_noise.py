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

**Texture.** A phase may also get a fine texture (``pore_texture``, ``grain_texture``:
its variance and correlation length ``(v, sigma)``): white noise filtered by a Gaussian
of ``sigma`` voxels, of variance ``v`` (`texture_spectrum`), the grain and pore
texture a scan holds below the scale of its structure and that the noise spectra,
measured on second differences, do not see (`synthpack.measure.semivariogram`). Its
spectrum is added to the phase's noise spectrum before the filtering, so one field
carries both.

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
from ..measure.semivariogram import LAGS
from ..measure.spectrum import NPS_PATCH, patch_lags, patch_ring_powers, slice_difference_gain
from ..errors import SynthpackInputError
from ._base import BlockContext, Transform
from ._param import Param

if TYPE_CHECKING:
    import torch

    from .torch_blocks import DeviceVolume

__all__ = ["ColouredNoise", "TEXTURE_SIGMAS", "TILE", "fit_noise_and_texture", "highpass_variance_of_spectrum",
           "ring_powers_of_spectrum", "semivariogram_of_spectrum", "spectrum_for_rings", "texture_spectrum"]

#: Period (voxels) of the noise cubes along each axis.
TILE = 64
#: The correlation lengths (voxels) a texture is fitted over (`fit_noise_and_texture`).
TEXTURE_SIGMAS = tuple(round(0.3 + 0.1 * i, 1) for i in range(28))
#: Each ring power's (and the noise level's) fit error is weighed relative to its own
#: target, but to no less than this fraction of the largest (`_ring_weights`): a scan's ring
#: powers span decades (the concrete neutron CT's pores: 770,000 down to 860 from the first
#: ring to the sixth), and the realism target is a factor in every ring.
RING_WEIGHT_FLOOR = 1e-3


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


def semivariogram_of_spectrum(spectrum: np.ndarray, lags: int = LAGS) -> np.ndarray:
    """Expected in-slice semivariogram (`synthpack.measure.semivariogram`) of noise with 3D spectrum `spectrum`.

    ``gamma(k) = mean(S(f) (1 - cos(2 pi f_x k)))``, averaged over the y and x axes.

    Parameters
    ----------
    spectrum : ndarray of float64, shape (T, T, T)
        As for `ring_powers_of_spectrum`.
    lags : int
        Lags ``1 .. lags`` voxels.

    Returns
    -------
    ndarray of float64, shape (lags,)
        Intensity units squared.
    """
    f = np.fft.fftfreq(spectrum.shape[0])
    marginal_y, marginal_x = spectrum.mean(axis=(0, 2)), spectrum.mean(axis=(0, 1))
    return np.array([np.mean([np.sum(m * (1.0 - np.cos(2.0 * np.pi * f * k))) / len(f)
                              for m in (marginal_y, marginal_x)]) for k in range(1, lags + 1)])


def texture_spectrum(variance: float, sigma: float, tile: int = TILE) -> np.ndarray:
    """The 3D spectrum of white noise filtered by a Gaussian of `sigma` voxels, scaled to `variance`.

    Parameters
    ----------
    variance : float
        Intensity units squared (>= 0).
    sigma : float
        Correlation length, voxels (> 0).
    tile : int

    Returns
    -------
    ndarray of float64, shape (tile, tile, tile)
        ``S(f)`` with ``mean(S) = variance``; read-only.
    """
    f = np.fft.fftfreq(tile)
    gain = np.exp(-4.0 * np.pi**2 * sigma**2 * f**2)
    spectrum = gain[:, None, None] * gain[None, :, None] * gain[None, None, :]
    spectrum *= variance / spectrum.mean()
    spectrum.flags.writeable = False
    return spectrum


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
        relative to its target (`_ring_weights`), so that the weak outer rings are matched
        as closely, as a factor, as the strong inner ones.
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
    weight = _ring_weights(target)
    knots, _ = _nonnegative_least_squares(response * weight[:, None], target * weight)
    spectrum = np.tensordot(knots, hats, axes=1)
    spectrum.flags.writeable = False
    return spectrum


#: Iterations `_nonnegative_least_squares` allows per unknown: SciPy's default, 3, stops short of the
#: solution on ill-conditioned fits (a concrete pack's rings spanning three decades needed about 30).
NNLS_ITERATIONS = 100


def _nonnegative_least_squares(matrix: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float]:
    """`scipy.optimize.nnls` of ``matrix @ x = target`` with room to converge: ``(x >= 0, residual norm)``."""
    return optimize.nnls(matrix, target, maxiter=NNLS_ITERATIONS * matrix.shape[1])


def _ring_weights(target: np.ndarray) -> np.ndarray:
    """Least-squares weights of ring-power (and noise-level) targets: ``1 / (2 max(target, RING_WEIGHT_FLOOR * max))``.

    Parameters
    ----------
    target : ndarray of float64, shape (R,)
        Non-negative targets, intensity units squared: the ring powers (and the noise level's
        variance).

    Returns
    -------
    ndarray of float64, shape (R,)
        Each error then counts as a fraction of its target (a factor, as the realism target
        reads the rings); a target near 0 (the pack already has that ring's power) as a
        fraction of `RING_WEIGHT_FLOOR` times the largest. The factor 1/2 keeps the rings'
        weight against the semivariogram's in `fit_noise_and_texture` (each lag relative to its
        own value) where the spectrum is flat, as it was when every error was taken relative to
        its target plus the largest.
    """
    return 0.5 / np.maximum(target, max(RING_WEIGHT_FLOOR * float(target.max()), np.finfo(float).tiny))


@functools.lru_cache(maxsize=128)
def _responses(n_rings: int, highpass: bool, sigma: float | None, tile: int = TILE) -> np.ndarray:
    """Ring powers, highpass variance (if `highpass`) and semivariogram of the knots' hats
    (``sigma`` None; shape (rows, knots)) or of a unit-variance texture of `sigma` (shape (rows, 1))."""
    spectra = (_hats(n_rings + highpass, tile) if sigma is None else texture_spectrum(1.0, sigma, tile)[None])
    rows = [[*ring_powers_of_spectrum(s, n_rings), *([highpass_variance_of_spectrum(s)] if highpass else []),
             *semivariogram_of_spectrum(s)] for s in spectra]
    return np.asarray(rows).T


def fit_noise_and_texture(
    powers: Sequence[float], highpass: float | None, semivariogram: Sequence[float] | None,
    scale: Sequence[float] | None = None, tile: int = TILE,
) -> tuple[tuple[float, ...], float | None, list[float] | None]:
    """Split what a pack lacks into noise (`spectrum_for_rings`) and a fine texture (`texture_spectrum`).

    The ring powers and noise level that second differences measure see little of a
    texture correlated over a voxel or two; the semivariogram sees both. One spectrum,
    the knots of `spectrum_for_rings` plus a texture of one of `TEXTURE_SIGMAS`, is fitted
    to all of them by non-negative least squares (the rings and the level weighed as in
    `spectrum_for_rings`, each lag relative to `scale`), for each correlation length; the
    best fit wins. Without a `semivariogram`, the noise of the clipped `powers` and
    `highpass` and no texture.

    Parameters
    ----------
    powers : sequence of float
        Ring powers to add (``k = 1, 2, ...``; may be negative where the pack has more), intensity units squared.
    highpass : float or None
        Noise variance to add (`highpass_variance_of_spectrum`), or None (not matched).
    semivariogram : sequence of float or None
        Semivariogram to add at lags ``1, 2, ...`` voxels (`synthpack.measure.semivariogram`), or None.
    scale : sequence of float, optional
        The source's semivariogram, which each lag's error is taken relative to (default `semivariogram`).
    tile : int

    Returns
    -------
    powers : tuple of float
        The noise's ring powers (>= 0): with `highpass`, what `ColouredNoise` synthesises the noise from.
    highpass : float or None
        The noise's variance as `highpass_variance_of_spectrum` sees it.
    texture : list of 2 float or None
        ``[variance, sigma]`` of the texture; None where none is fitted.
    """
    powers = np.asarray(powers, dtype=np.float64)
    clipped = np.maximum(powers, 0.0)
    high = None if highpass is None else max(float(highpass), 0.0)
    if semivariogram is None:
        return tuple(clipped.tolist()), high, None
    noise_target = np.append(clipped, [] if high is None else [high])
    target = np.concatenate([np.append(powers, [] if high is None else [highpass]), semivariogram])
    scale = np.abs(np.asarray(semivariogram if scale is None else scale, dtype=np.float64))
    weight = np.concatenate([_ring_weights(noise_target), 1.0 / np.maximum(scale, np.finfo(float).tiny)])
    hats = _responses(len(powers), high is not None, None, tile)
    best: tuple[float, np.ndarray, float] | None = None
    for sigma in TEXTURE_SIGMAS:
        response = np.hstack([hats, _responses(len(powers), high is not None, sigma, tile)])
        solution, residual = _nonnegative_least_squares(response * weight[:, None], target * weight)
        if best is None or residual < best[0]:
            best = (residual, solution, sigma)
    _, solution, sigma = best
    noise = hats @ solution[:-1]
    variance = float(solution[-1])
    return (tuple(noise[: len(powers)].tolist()), None if high is None else float(noise[len(powers)]),
            [variance, sigma] if variance > 0 else None)


@functools.lru_cache(maxsize=8)
def _field(powers: tuple[float, ...], highpass: float | None, texture: tuple[float, ...] | None, tile: int,
           key: tuple[int, ...]) -> np.ndarray:
    """A periodic cube of noise of `spectrum_for_rings` plus `texture_spectrum` of ``texture = (variance, sigma)``,
    from the white noise of `key`; float32, read-only."""
    spectrum = np.zeros((tile,) * 3)
    if any(powers) or highpass:
        spectrum = spectrum + spectrum_for_rings(powers, highpass, tile)
    if texture is not None and texture[0] > 0:
        spectrum = spectrum + texture_spectrum(float(texture[0]), float(texture[1]), tile)
    if not spectrum.any():
        field = np.zeros((tile,) * 3, dtype=np.float32)
    else:
        white = np.random.default_rng(list(key)).standard_normal((tile,) * 3)
        field = np.fft.ifftn(np.fft.fftn(white) * np.sqrt(spectrum)).real.astype(np.float32)
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
    pore_texture, grain_texture : list of 2 float or None
        A fine texture in each phase, ``(variance, sigma)``: intensity units squared and
        its correlation length, voxels (`texture_spectrum`). Default None (none).
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
        Param("pore_texture", kind="floats", minimum=0.0, optional=True, rangeable=False),
        Param("grain_texture", kind="floats", minimum=0.0, optional=True, rangeable=False),
    )

    def __init__(
        self, pore_power: Sequence[float], grain_power: Sequence[float], pore_level: float, grain_level: float,
        pore_std: float | None = None, grain_std: float | None = None,
        pore_texture: Sequence[float] | None = None, grain_texture: Sequence[float] | None = None, *, p: float = 1.0,
    ) -> None:
        for name, texture in (("pore_texture", pore_texture), ("grain_texture", grain_texture)):
            if texture is not None and (len(texture) != 2 or not texture[1] > 0):
                raise SynthpackInputError(f"{name} must be (variance, sigma) with sigma > 0 voxels, not {texture!r}")
        super().__init__(pore_power=pore_power, grain_power=grain_power, pore_level=pore_level,
                         grain_level=grain_level, pore_std=pore_std, grain_std=grain_std,
                         pore_texture=pore_texture, grain_texture=grain_texture, p=p)

    @staticmethod
    def _tiles(key: tuple[int, ...], **params: Any) -> tuple[np.ndarray, np.ndarray]:
        """The pore and the grain noise cubes of the white noise of `key`: float32, shape (TILE,) * 3, read-only."""
        pore, grain = (_field(tuple(params[f"{phase}_power"]), _square(params[f"{phase}_std"]),
                              None if params[f"{phase}_texture"] is None else tuple(params[f"{phase}_texture"]),
                              TILE, key + (k,))
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
