"""The block steps of `synthpack.artefacts.blockwise` on a torch device (a CUDA GPU where there is one).

`DeviceSteps` gives, for each transform that has one, the torch version of its
`~synthpack.artefacts.Transform._transform_block`: the same values on a block of
the volume, within float32 rounding, with the arithmetic on the device and every
random draw made on the CPU by the NumPy module's own code from the same generators,
so the noise realisations and ring radii are the NumPy path's:

- `GaussianBlur`, `MotionBlur`: the NumPy module's kernel (`gaussian_kernel`,
  `line_kernel`), the block mirrored beyond its edges as SciPy's ``"reflect"``
  (NumPy's ``"symmetric"``) mirrors it, then weighted sums of shifted copies (the
  Gaussian separably, axis after axis) in float64, rounded to float32 after each axis
  as SciPy rounds: plain multiply-adds, so no reduced-precision (TF32) convolution can
  enter, and the values are SciPy's but for the order of the sum. (A float32 sum
  differs in the last bits, which the coloured noise's ``sqrt`` of the grain
  fraction amplifies near the pore level to about 1e-5 of the intensity range.)
- `ColouredNoise`: its pore and grain noise tiles are made on the CPU
  (`ColouredNoise._tiles`) and moved to the device once per volume; the periodic
  gather and the mixing by phase fraction run there.
- `BeamHardening`, `RingArtefacts`: the slice's cupping factor (`cupping_factor`) or
  ring pattern (`RingArtefacts._pattern`, radii drawn from the call's seed) is
  computed once per volume by the NumPy code and kept on the device; each block is
  scaled or shifted by its window there.
- `GaussianNoise`, `SpeckleNoise`: the block's white noise is drawn on the CPU from
  the block's generator, slab by slab as the NumPy transform draws it
  (`noise._standard_noise`), then scaled and applied on the device.
- `ContrastGamma`: its response (`intensity.response`) evaluated on the device.

Like the NumPy steps, a step never modifies its input block (which may share memory
with the source volume on the CPU device).

Other transforms (`PoissonNoise`, `CTSimulation`) have no torch version
(`without_torch` names them), and `apply_blockwise` runs a pipeline that has not
on the CPU as a whole. This module imports torch; `blockwise` imports it only when
asked for a device.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import torch

from .._shared.arrays import cupping_factor, periodic_indices
from .._shared.arrays import float32_value as _f32
from ._base import Transform
from .blur import GaussianBlur, MotionBlur, gaussian_kernel, line_kernel
from .coloured_noise import ColouredNoise
from .intensity import ContrastGamma, response
from .noise import GaussianNoise, SpeckleNoise, _standard_noise
from .radial import BeamHardening, RingArtefacts, _window

__all__ = ["DeviceSteps", "without_torch"]

#: ``step(volume, transform, block, rng, call, origin, shape, **params) -> block``, as `_transform_block`.
Step = Callable[..., torch.Tensor]


class _Volume:
    """One step's device-side state for one volume: what it computes once and keeps (tiles, slice tables)."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self._kept: dict[Any, Any] = {}
        self._lock = threading.Lock()

    def put(self, array: np.ndarray) -> torch.Tensor:
        """`array` as a tensor on the device."""
        return _put(array, self.device)

    def once(self, key: Any, make: Callable[[], Any]) -> Any:
        """``make()``, computed on the first call with `key` and kept for the volume's other blocks."""
        with self._lock:
            if key not in self._kept:
                self._kept[key] = make()
            return self._kept[key]


def _put(array: np.ndarray, device: torch.device) -> torch.Tensor:
    """`array` as a tensor on `device` (a read-only array is copied first: torch wants writable memory)."""
    return torch.as_tensor(array if array.flags.writeable else array.copy(), device=device)


def _mirrored(volume: _Volume, block: torch.Tensor, halo: Iterable[int]) -> torch.Tensor:
    """`block` extended by `halo` voxels on both sides of each axis, mirrored (NumPy ``"symmetric"``)."""
    for axis, h in enumerate(halo):
        if h:
            n = block.shape[axis]
            index = np.arange(-h, n + h) % (2 * n)
            index = np.where(index < n, index, 2 * n - 1 - index)
            block = block.index_select(axis, volume.put(index))
    return block


def _correlate(padded: torch.Tensor, kernel: np.ndarray) -> torch.Tensor:
    """The "valid" correlation of `padded` with `kernel` (same number of axes): ``sum_k kernel[k] padded[k:k+n]``.

    Summed in float64 over the non-zero weights and rounded to float32 once, as SciPy's
    filters sum and round (so the result is theirs but for the order of the sum). The
    output is smaller than `padded` by ``kernel.shape - 1`` on each axis.
    """
    shape = [int(n) - k + 1 for n, k in zip(padded.shape, kernel.shape)]
    wide = padded.to(torch.float64)
    out = torch.zeros(shape, dtype=torch.float64, device=padded.device)
    for offset in zip(*np.nonzero(kernel)):
        out.add_(wide[tuple(slice(int(o), int(o) + n) for o, n in zip(offset, shape))], alpha=float(kernel[offset]))
    return out.to(torch.float32)


def _gaussian_blur(volume: _Volume, transform: GaussianBlur, block: torch.Tensor, rng: np.random.Generator,
                   call: np.random.SeedSequence, origin: tuple[int, int, int], shape: tuple[int, int, int], *,
                   sigma: float) -> torch.Tensor:
    if sigma == 0:
        return block.clone()
    kernel = gaussian_kernel(sigma)
    out = _mirrored(volume, block, (kernel.size // 2,) * 3)
    for axis in range(3):
        out = _correlate(out, kernel.reshape([-1 if a == axis else 1 for a in range(3)]))
    return out


def _motion_blur(volume: _Volume, transform: MotionBlur, block: torch.Tensor, rng: np.random.Generator,
                 call: np.random.SeedSequence, origin: tuple[int, int, int], shape: tuple[int, int, int], *,
                 length: float, angle: float) -> torch.Tensor:
    kernel = line_kernel(length, angle).astype(np.float32)  # the weights MotionBlur gives SciPy
    if kernel.size == 1:
        return block.clone()
    half = kernel.shape[0] // 2
    # SciPy's convolve is a correlation with the flipped kernel
    return _correlate(_mirrored(volume, block, (0, half, half)), np.flip(kernel)[None])


def _coloured_noise(volume: _Volume, transform: ColouredNoise, block: torch.Tensor, rng: np.random.Generator,
                    call: np.random.SeedSequence, origin: tuple[int, int, int], shape: tuple[int, int, int],
                    **params: Any) -> torch.Tensor:
    key = transform._call_key(call)
    tiles = volume.once(("tiles", key), lambda: [volume.put(t) for t in transform._tiles(key, **params)])
    pore_field, grain_field = (_periodic_window(volume, tile, origin, block.shape) for tile in tiles)
    contrast = params["grain_level"] - params["pore_level"]
    grain = ((block - _f32(params["pore_level"])) / _f32(contrast if contrast else 1.0)).clamp_(0.0, 1.0)
    pore = 1.0 - grain
    pore_field *= pore.sqrt_()
    grain_field *= grain.sqrt_()
    pore_field += grain_field
    return pore_field.add_(block)


def _periodic_window(volume: _Volume, tile: torch.Tensor, origin: tuple[int, ...],
                     shape: Iterable[int]) -> torch.Tensor:
    """`synthpack._shared.arrays.periodic_window` on the device: the same indices, gathered there."""
    out = tile
    for axis, index in enumerate(periodic_indices(origin, tuple(shape), tile.shape)):
        out = out.index_select(axis, volume.put(index))
    return out


def _beam_hardening(volume: _Volume, transform: BeamHardening, block: torch.Tensor, rng: np.random.Generator,
                    call: np.random.SeedSequence, origin: tuple[int, int, int], shape: tuple[int, int, int], *,
                    strength: float, keep: str) -> torch.Tensor:
    factor = volume.once("factor", lambda: volume.put(cupping_factor(shape, strength, keep)))
    return block * factor[_window(origin, block.shape)]


def _ring_artefacts(volume: _Volume, transform: RingArtefacts, block: torch.Tensor, rng: np.random.Generator,
                    call: np.random.SeedSequence, origin: tuple[int, int, int], shape: tuple[int, int, int],
                    **params: Any) -> torch.Tensor:
    pattern = volume.once("pattern", lambda: volume.put(transform._pattern(shape, np.random.default_rng(call),
                                                                            **params)))
    return block + pattern[_window(origin, block.shape)]


def _gaussian_noise(volume: _Volume, transform: GaussianNoise, block: torch.Tensor, rng: np.random.Generator,
                    call: np.random.SeedSequence, origin: tuple[int, int, int], shape: tuple[int, int, int], *,
                    std: float) -> torch.Tensor:
    out = torch.empty_like(block)
    for rows, noise in _standard_noise(tuple(block.shape), rng):
        torch.add(block[rows], volume.put(noise).mul_(_f32(std)), out=out[rows])
    return out


def _speckle_noise(volume: _Volume, transform: SpeckleNoise, block: torch.Tensor, rng: np.random.Generator,
                   call: np.random.SeedSequence, origin: tuple[int, int, int], shape: tuple[int, int, int], *,
                   std: float) -> torch.Tensor:
    out = torch.empty_like(block)
    for rows, noise in _standard_noise(tuple(block.shape), rng):
        torch.mul(block[rows], volume.put(noise).mul_(_f32(std)).add_(1.0), out=out[rows])
    return out


def _contrast_gamma(volume: _Volume, transform: ContrastGamma, block: torch.Tensor, rng: np.random.Generator,
                    call: np.random.SeedSequence, origin: tuple[int, int, int], shape: tuple[int, int, int],
                    **params: Any) -> torch.Tensor:
    return response(block, torch.sign, **params)


#: The torch step of each transform class that has one.
_STEPS: dict[type[Transform], Step] = {
    GaussianBlur: _gaussian_blur,
    MotionBlur: _motion_blur,
    ColouredNoise: _coloured_noise,
    BeamHardening: _beam_hardening,
    RingArtefacts: _ring_artefacts,
    GaussianNoise: _gaussian_noise,
    SpeckleNoise: _speckle_noise,
    ContrastGamma: _contrast_gamma,
}


def without_torch(transforms: Iterable[Transform]) -> list[str]:
    """The names of the `transforms` that have no torch version (empty: the pipeline runs on a device)."""
    return [t.name for t in transforms if type(t) not in _STEPS]


class DeviceSteps:
    """The block steps on a torch device: blocks go there, are transformed there, and come back.

    Parameters
    ----------
    device : str
        A torch device, e.g. ``"cuda"`` (or ``"cpu"``: the same arithmetic, for tests).
    """

    def __init__(self, device: str) -> None:
        self.device = torch.device(device)

    def put(self, block: np.ndarray) -> torch.Tensor:
        """A float32 block (z, y, x) onto the device."""
        return _put(block, self.device)

    @staticmethod
    def get(block: torch.Tensor) -> np.ndarray:
        """A block back as a float32 NumPy array."""
        return block.cpu().numpy()

    def step(self, transform: Transform) -> Callable[..., torch.Tensor]:
        """The torch `_transform_block` of `transform`, for one volume (it keeps that volume's tables)."""
        return functools.partial(_STEPS[type(transform)], _Volume(self.device), transform)
