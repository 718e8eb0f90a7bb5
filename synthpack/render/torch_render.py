"""The render on a torch device (a CUDA GPU where there is one): `synthpack.render.reconstruct.render_chunk` in torch.

`TorchRenderer` renders a chunk as `~synthpack.render.reconstruct.render_chunk` does (the
same pose maps, prepared crops, claims, partial-volume compositing and background),
with the grains' mask, signed distance and intensity interpolated linearly on the
device over each grain's box. Coordinates and interpolation weights are computed in
float64, summed in the order SciPy's ``affine_transform`` sums them, so labels equal
the NumPy render's except where a voxel's interpolated mask value lies within float
rounding of the 0.5 threshold (`TorchRenderer.near_threshold` counts those voxels)
and intensities agree within float32 rounding. Only linear interpolation of the
intensities (``order: 1``, the default) is offered on the device: `resolve_device`
keeps other orders on the CPU.

The device is chosen by ``reconstruct.device`` (`resolve_device`): ``auto`` (the
default) renders on the first CUDA GPU when torch sees one, else with NumPy on the
CPU, as before. The post-processing runs on the same device
(`synthpack.artefacts.torch_blocks`, whatever the render's order) where every transform
of its pipeline has a torch version, else on the CPU.
"""

from __future__ import annotations

import glob
import logging
import sys
from typing import Any, Sequence

import numpy as np

from ..errors import SynthpackInputError
from .partial_volume import FAR, PAD, PartialVolume
from .reconstruct import Background, Grid, PoseMaps, RenderCrop, background_values, grain_boxes

logger = logging.getLogger(__name__)

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
        raise SynthpackInputError(f"reconstruct.device {device}: torch sees no CUDA GPU here; use auto or cpu")
    count = torch.cuda.device_count()
    if device.startswith("cuda:") and int(device[5:]) >= count:
        raise SynthpackInputError(f"reconstruct.device {device}: torch sees {count} CUDA GPU(s) here, cuda:0 to "
                                  f"cuda:{count - 1}; use one of them, cuda, auto or cpu")
    if order != 1:
        raise SynthpackInputError(f"reconstruct.device {device} renders with order 1 only; use order: 1 "
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
    """`~synthpack.render.reconstruct.render_chunk` on a torch device, with its crops kept there.

    Call it with `render_chunk`'s arguments (as `~synthpack.render.reconstruct.reconstruct`'s
    ``renderer``); it returns what `render_chunk` returns, as NumPy arrays.

    Parameters
    ----------
    device : str
        A torch device, e.g. ``"cuda"`` (or ``"cpu"``: the same arithmetic, for tests).

    Attributes
    ----------
    near_threshold : int
        Voxels rendered so far whose interpolated mask value lies within 1e-6 of the
        0.5 threshold: the only voxels whose label may differ from the NumPy render's.
    """

    def __init__(self, device: str) -> None:
        import torch

        self.torch = torch
        self.device = torch.device(device)
        self.near_threshold = 0
        self._crops: dict[int, tuple[Any, Any, Any]] = {}

    def _crop(self, index: int, crop: RenderCrop) -> tuple[Any, Any, Any]:
        """The crop's mask, intensity and distance as float64 tensors on the device (kept for later chunks)."""
        if index not in self._crops:
            def tensor(array: np.ndarray | None) -> Any:
                return None if array is None else self.torch.as_tensor(
                    np.asarray(array, dtype=np.float64), device=self.device)
            self._crops[index] = (tensor(crop.mask), tensor(crop.intensity), tensor(crop.distance))
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
        tomogram = torch.as_tensor(background_values(grid, lo, hi, background, tube, seed), device=self.device)
        labels = torch.zeros(shape, dtype=torch.int32, device=self.device)
        claim = torch.zeros(shape, dtype=torch.float32, device=self.device)
        occupancy = value = None
        if partial_volume is not None:
            occupancy = torch.zeros(shape, dtype=torch.float32, device=self.device)
            value = torch.zeros(shape, dtype=torch.float32, device=self.device)
        contested = 0
        for i, sub_lo, sub_hi, offset in grain_boxes(maps, lo, hi):
            index = int(maps.library_index[i])
            mask, intensity, distance = self._crop(index, crops[index])
            matrix = maps.matrix[i]
            window = tuple(slice(int(a - b), int(c - b)) for a, b, c in zip(sub_lo, lo, sub_hi))
            base = self._mapped(matrix, tuple(int(n) for n in sub_hi - sub_lo))
            weight = _linear(torch, mask, _shift(base, offset + 1.0), cval=0.0).to(torch.float32)
            self.near_threshold += int(torch.count_nonzero((weight - 0.5).abs() < 1e-6))
            inside = weight > 0.5
            region_claim = claim[window]
            contested += int(torch.count_nonzero(inside & (region_claim > 0.5)))
            wins = inside & (weight > region_claim)
            labels[window][wins] = int(i) + 1
            region_claim[wins] = weight[wins]
            if partial_volume is None:
                coordinates = _shift(base, offset)
                sampled = _linear(torch, intensity, coordinates, cval=None)
                tomogram[window][wins] = sampled.to(torch.float32)[wins]
                continue
            coordinates = _shift(base, offset + PAD)
            scale = np.float32(abs(np.linalg.det(matrix)) ** (-1.0 / 3.0))
            grain_distance = _linear(torch, distance, coordinates, cval=FAR).to(torch.float32)
            grain = torch.clamp(grain_distance * float(scale) - float(np.float32(partial_volume.shift - 0.5)),
                                0.0, 1.0)
            occupancy[window] += grain
            sampled = _linear(torch, intensity, coordinates, cval=None).to(torch.float32)
            value[window] += grain * sampled
        if occupancy is not None:
            tomogram *= 1.0 - torch.clamp(occupancy, max=1.0)
            tomogram += value * (1.0 / torch.clamp(occupancy, min=1.0))
        return tomogram.cpu().numpy(), labels.cpu().numpy(), contested

    def _mapped(self, matrix: np.ndarray, shape: tuple[int, int, int]) -> Any:
        """``matrix @ o`` (float64, shape (3, *shape)) of every box index ``o``, summed as SciPy sums it."""
        torch = self.torch
        axes = torch.meshgrid(*(torch.arange(n, dtype=torch.float64, device=self.device) for n in shape),
                              indexing="ij")
        rows = []
        for row in range(3):
            mapped = axes[0] * float(matrix[row, 0])
            for column in (1, 2):
                mapped = mapped + axes[column] * float(matrix[row, column])
            rows.append(mapped)
        return torch.stack(rows)


def _shift(mapped: Any, shift: np.ndarray) -> Any:
    """``mapped + shift`` per axis (the crop coordinates of an affine offset `shift`)."""
    return mapped + mapped.new_tensor(np.asarray(shift, dtype=np.float64)).reshape(3, 1, 1, 1)


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
