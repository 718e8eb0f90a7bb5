"""The render on a torch device (a CUDA GPU where there is one): `TorchRenderer`, and `resolve_device`.

`TorchRenderer` renders a chunk as `~synthpack.render.numpy_render.render_chunk` does, with
the same code: the same pose maps, prepared crops and background, and the same
`~synthpack.render.canvas.Canvas` for the claims and the partial-volume compositing, run
on torch tensors. It visits every voxel of each grain's box (no support search) and
interpolates the grains' signed distance (of their smooth surface) and intensity
linearly on the device. Coordinates and interpolation weights are computed in float64,
summed in the order SciPy's ``affine_transform`` sums them, so labels equal the NumPy
render's except where a voxel's interpolated signed distance lies within float rounding
of 0 (`TorchRenderer.near_threshold` counts those voxels) and intensities agree within
float32 rounding. Only linear interpolation of the intensities (``order: 1``, the
default) is offered on the device: `resolve_device` keeps other orders on the CPU.

The device is chosen by ``run.device`` (`resolve_device`): ``auto`` (the
default) renders on the first CUDA GPU when torch sees one, else with NumPy on the
CPU, as before. The post-processing runs on the same device
(`synthpack.artefacts.torch_blocks`, whatever the render's order) where every transform
of its pipeline has a torch version, else on the CPU.
"""

from __future__ import annotations

import glob
import sys
from typing import Any, Sequence

import numpy as np

from ..errors import SynthpackInputError
from .background import Background, background_values
from .canvas import Canvas
from .crops import RenderCrop
from .grid import Grid
from .partial_volume import PartialVolume
from .poses import PoseMaps, grain_boxes, mapped

__all__ = ["TorchRenderer", "resolve_device"]


def resolve_device(device: str, order: int = 1) -> str | None:
    """The torch device to render (or post-process) on, or None for NumPy on the CPU.

    Parameters
    ----------
    device : str
        ``"auto"`` (the first CUDA GPU torch sees, else None; on Linux without a
        ``/dev/nvidia<N>`` device torch is not even imported), ``"cpu"`` (None: the
        NumPy render) or ``"cuda"`` / ``"cuda:N"`` (that GPU; an error without one).
    order : int
        Interpolation order of the render's intensities; only 1 runs on the device (the
        post-processing asks with the default, 1: it runs there whatever the render's order).

    Raises
    ------
    SynthpackInputError
        For a CUDA device torch does not see (no GPU, or a GPU number beyond the last), or
        another order than 1 asked of one.
    """
    if device == "cpu" or (device == "auto" and not _may_have_cuda()):
        return None
    import torch

    available = torch.cuda.is_available()
    if device == "auto":
        return "cuda" if available and order == 1 else None
    if not available:
        raise SynthpackInputError(f"run.device {device}: torch sees no CUDA GPU here; use auto or cpu")
    count = torch.cuda.device_count()
    if device.startswith("cuda:") and int(device[5:]) >= count:
        raise SynthpackInputError(f"run.device {device}: torch sees {count} CUDA GPU(s) here, cuda:0 to "
                                  f"cuda:{count - 1}; use one of them, cuda, auto or cpu")
    if order != 1:
        raise SynthpackInputError(f"run.device {device} renders with order 1 only; use order: 1 "
                                  "or device: cpu")
    return device


def _may_have_cuda() -> bool:
    """False where no CUDA GPU can be present, without importing torch (seconds per process).

    On Linux a CUDA GPU shows as ``/dev/nvidia<N>``; elsewhere, or once torch is imported,
    torch is asked.
    """
    if "torch" in sys.modules or not sys.platform.startswith("linux"):
        return True
    return bool(glob.glob("/dev/nvidia[0-9]*"))


class TorchRenderer:
    """`~synthpack.render.numpy_render.render_chunk` on a torch device, with its crops kept there.

    Call it with `render_chunk`'s arguments (as `~synthpack.render.chunked.reconstruct`'s
    ``renderer``); it returns what `render_chunk` returns, as NumPy arrays. It draws every
    voxel of each grain's box on the chunk's `~synthpack.render.canvas.Canvas`, the NumPy
    render's code run on torch tensors.

    Parameters
    ----------
    device : str
        A torch device, e.g. ``"cuda"`` (or ``"cpu"``: the same arithmetic, for tests).

    Attributes
    ----------
    near_threshold : int
        Voxels rendered so far whose interpolated signed distance lies within 1e-6 voxels
        of 0: the only voxels whose label may differ from the NumPy render's.
    """

    def __init__(self, device: str) -> None:
        import torch

        self.torch = torch
        self.device = torch.device(device)
        self.near_threshold = 0
        self._crops: dict[int, RenderCrop] = {}

    def _crop(self, index: int, crop: RenderCrop) -> RenderCrop:
        """The crop's intensity and distance as float64 tensors on the device (kept for later chunks)."""
        if index not in self._crops:
            def tensor(array: np.ndarray) -> Any:
                return self.torch.as_tensor(
                    np.asarray(array, dtype=np.float64), device=self.device)
            self._crops[index] = RenderCrop(tensor(crop.intensity), tensor(crop.distance), None)
        return self._crops[index]

    def __call__(
        self,
        crops: Sequence[RenderCrop | None],
        maps: PoseMaps,
        grid: Grid,
        lo: np.ndarray,
        hi: np.ndarray,
        background: Background,
        *,
        tube: tuple[float, float, float] | None = None,
        order: int = 1,
        seed: int = 0,
        partial_volume: PartialVolume | None = None,
    ) -> tuple[np.ndarray, np.ndarray, int]:
        torch = self.torch
        if order != 1:
            raise SynthpackInputError(f"the torch render interpolates linearly (order 1), got order {order}")
        shape = tuple(int(n) for n in hi - lo)
        canvas = Canvas(torch.as_tensor(background_values(grid, lo, hi, background, tube, seed), device=self.device),
                        self._sample, torch, order, partial_volume)
        for i, sub_lo, sub_hi, offset in grain_boxes(maps, lo, hi):
            index = int(maps.library_index[i])
            voxels, where = self._box(sub_lo - lo, sub_hi - lo, shape)
            distance = canvas.draw(i + 1, voxels, mapped(maps.matrix[i], where, torch), offset,
                                   self._crop(index, crops[index]), maps.matrix[i])
            self.near_threshold += int(torch.count_nonzero(distance.abs() < 1e-6))
        canvas.finish()
        return canvas.tomogram.cpu().numpy(), canvas.labels.cpu().numpy(), canvas.contested

    def _box(self, lo: np.ndarray, hi: np.ndarray, shape: tuple[int, int, int]) -> tuple[Any, tuple[Any, Any, Any]]:
        """Every voxel of the box ``[lo, hi)`` of a chunk of `shape`: flat chunk indices and (float64) box indices."""
        torch = self.torch
        axes = torch.meshgrid(*(torch.arange(int(a), int(b), device=self.device) for a, b in zip(lo, hi)),
                              indexing="ij")
        index = ((axes[0] * shape[1] + axes[1]) * shape[2] + axes[2]).reshape(-1)
        where = tuple((axis - int(start)).reshape(-1).to(torch.float64) for axis, start in zip(axes, lo))
        return index, where

    def _sample(self, volume: Any, mapped: Any, shift: np.ndarray, order: int, cval: float | None) -> Any:
        """`~synthpack.render.canvas.Sampler` on the device, linear only (float32)."""
        coordinates = mapped + mapped.new_tensor(np.asarray(shift, dtype=np.float64)).reshape(3, 1)
        return _linear(self.torch, volume, coordinates, cval=cval).to(self.torch.float32)


def _linear(torch: Any, volume: Any, coordinates: Any, *, cval: float | None) -> Any:
    """`scipy.ndimage.map_coordinates` of `volume` at `coordinates` (3, ...) with order 1, float64.

    ``cval`` not None: SciPy's ``"constant"`` mode (points outside the volume take
    `cval`); None: its ``"nearest"`` mode (coordinates clipped to the volume).
    """
    size = [int(n) for n in volume.shape]
    clipped = [coordinates[axis].clamp(0, size[axis] - 1) for axis in range(3)]
    low = [torch.floor(c).long().clamp(max=max(size[axis] - 2, 0)) for axis, c in enumerate(clipped)]
    frac = [c - low[axis].to(torch.float64) for axis, c in enumerate(clipped)]
    high = [(low[axis] + 1).clamp(max=size[axis] - 1) for axis in range(3)]
    result = torch.zeros(coordinates.shape[1:], dtype=torch.float64, device=coordinates.device)
    for corner in range(8):
        bits = [(corner >> (2 - axis)) & 1 for axis in range(3)]
        weight = torch.ones_like(result)
        for axis, bit in enumerate(bits):
            weight = weight * (frac[axis] if bit else 1.0 - frac[axis])
        index = [high[axis] if bit else low[axis] for axis, bit in enumerate(bits)]
        result = result + weight * volume[index[0], index[1], index[2]]
    if cval is not None:
        outside = torch.zeros_like(result, dtype=torch.bool)
        for axis in range(3):
            outside |= (coordinates[axis] < 0) | (coordinates[axis] > size[axis] - 1)
        result = torch.where(outside, torch.full_like(result, float(cval)), result)
    return result
