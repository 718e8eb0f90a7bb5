"""Apply an artefact pipeline to a volume block by block, between arrays that may not fit in memory.

`apply_blockwise` reads the input volume (a NumPy array, a memory map or a Zarr
array) one block at a time, applies the pipeline and writes each block of the
output, so memory stays bounded by a few blocks whatever the volume's size.
What each transform needs beyond its block is declared by its ``locality``:

``"voxel"`` (noise, rings, beam hardening)
    A voxel's output depends on its own input and position only. Ring radii and
    other per-volume draws come from a generator that every block seeds alike;
    rings and cupping are centred on the WHOLE slice.
``"neighbourhood"`` (Gaussian and motion blur)
    The block is read with a halo of the kernel's radius (`Transform.halo`);
    where the halo crosses the volume's border it is filled by mirroring, which
    is the ``mode="reflect"`` the blur uses on a whole volume. The blurred block
    therefore equals, bit for bit, the same block of the blur of the whole volume.
``"slice"`` (CT simulation)
    Blocks are slabs of whole slices (Y, X), scanned slice by slice with one set
    of detector gains for the whole volume.

Transforms run in passes over the volume: each neighbourhood or slice transform
starts a pass (its halo must hold the finished output of the steps before it)
and the voxel transforms after it join that pass, so the default pipeline
(blur, rings, noise) is a single pass. A pipeline of several passes writes its
intermediate volumes to a `scratch` array.

**On a torch device** (``device``, e.g. ``"cuda"``): each block is moved to the
device, each transform's own torch step runs there
(`Transform._transform_block_torch`, defined beside its NumPy step) and the finished
block comes back; reading, the block loop, the passes and every random draw are the
same as on the CPU, so the result is the NumPy path's within float32 rounding. A
pipeline holding any transform without a torch step (`Transform.has_torch_step`) runs
on the CPU as a whole (logged at INFO), so a result never mixes the two.

Random draws, all from `seed`'s named streams (`synthpack._shared.seeds`): the ``p`` test
and the parameters of step ``k`` from ``"transform_params", k``, per-volume draws from
``"transform_volume", k``, and block noise from ``"transform_blocks", k, z0, y0, x0`` (the
block's first voxel). The result is a
function of the seed, the pipeline, the volume and the block shape only: not of
the thread count or the order in which blocks are done. Noise realisations
differ from `Transform.apply` on the whole volume (one generator drawn in
order); their statistics are the same.
"""

from __future__ import annotations

import functools
import logging
import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .._shared.chunks import bounded_map, chunk_boxes, thread_count
from .._shared.arrays import as_image
from .._shared.seeds import generator, stream
from ..errors import SynthpackInputError
from ._base import BlockContext, Compose, Transform

logger = logging.getLogger(__name__)

__all__ = ["apply_blockwise", "device_for", "steps"]

@dataclass(frozen=True)
class _Step:
    """One transform of the pipeline with its drawn parameters."""

    index: int
    transform: Transform
    params: dict[str, Any]


def steps(pipeline: Transform | Compose) -> list[Transform]:
    """The transforms of `pipeline` in order, nested `Compose` flattened."""
    if isinstance(pipeline, Transform):
        return [pipeline]
    return [t for entry in pipeline for t in steps(entry)]


def _draw(pipeline: Transform | Compose, seed: int) -> list[_Step]:
    drawn = []
    for k, transform in enumerate(steps(pipeline)):
        rng = generator(seed, "transform_params", k)
        if transform.p < 1.0 and rng.random() >= transform.p:
            logger.debug("%s skipped (p=%g)", transform.name, transform.p)
            continue
        drawn.append(_Step(k, transform, transform.sample(rng)))
    return drawn


def _passes(drawn: list[_Step]) -> list[list[_Step]]:
    """Split the steps into passes: every non-voxel step starts one, voxel steps join the current one.

    A non-voxel step reads a halo or whole slices of its input, which must then be
    the complete output of the steps before it: hence a new pass.
    """
    passes: list[list[_Step]] = []
    for step in drawn:
        if not passes or step.transform.locality != "voxel":
            passes.append([step])
        else:
            passes[-1].append(step)
    return passes


def _blocks(shape: tuple[int, int, int], chunks: tuple[int, int, int], by_slice: bool):
    if not by_slice:
        return chunk_boxes(shape, chunks)
    slab = (max(1, math.prod(chunks) // (shape[1] * shape[2])), shape[1], shape[2])
    return chunk_boxes(shape, slab)


def _read_with_halo(source: Any, lo: np.ndarray, hi: np.ndarray, halo: np.ndarray) -> np.ndarray:
    """``source[lo - halo : hi + halo]`` as float32, mirrored (numpy "symmetric") beyond the volume."""
    shape = np.asarray(source.shape)
    start = np.maximum(lo - halo, 0)
    stop = np.minimum(hi + halo, shape)
    block = as_image(source[tuple(slice(a, b) for a, b in zip(start, stop))])
    pad = [(int(a), int(b)) for a, b in zip(start - (lo - halo), (hi + halo) - stop)]
    return np.pad(block, pad, mode="symmetric") if any(a or b for a, b in pad) else block


class _HaloReads:
    """`_read_with_halo` of the blocks of a stored volume, a row of blocks at a time.

    A stored volume (Zarr) decodes whole chunks: the pack's are single slices of a block,
    so a block read with a halo across y and x decodes its eight neighbours' slices too (a
    3.8x slower read than without halo on a pack's clean volume, measured). Each row of
    blocks (the same z and y span) is read once, with its halo, as one strip across the
    whole x range, and each block is cut from it: the same values, about half the decoding
    (a 150-million-voxel pack: 3.8 s against 7.8 s). The last `KEEP` strips are kept, read
    once by the first thread that asks (threads take blocks in order, so the blocks in
    flight lie in one or two rows).
    """

    #: Strips kept (each ``chunk z + 2 halo`` by ``chunk y + 2 halo`` by the volume's x width).
    KEEP = 2

    def __init__(self, source: Any, halo: np.ndarray) -> None:
        self._source, self._halo = source, halo
        self._lock = threading.Lock()
        self._strips: OrderedDict[tuple[int, ...], Future] = OrderedDict()

    def __call__(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        key = (int(lo[0]), int(hi[0]), int(lo[1]), int(hi[1]))
        with self._lock:
            strip = self._strips.get(key)
            mine = strip is None
            if mine:
                strip = self._strips[key] = Future()
                while len(self._strips) > self.KEEP:
                    self._strips.popitem(last=False)
            else:
                self._strips.move_to_end(key)
        if mine:
            row_lo, row_hi = np.array([lo[0], lo[1], 0]), np.array([hi[0], hi[1], self._source.shape[2]])
            try:
                strip.set_result(_read_with_halo(self._source, row_lo, row_hi, self._halo))
            except BaseException as error:  # the threads waiting on this strip raise it too
                strip.set_exception(error)
        width = int(hi[2] - lo[2]) + 2 * int(self._halo[2])
        return strip.result()[:, :, int(lo[2]) : int(lo[2]) + width].copy()  # steps may work in place


class _Where(Protocol):
    """Where the steps run: blocks put there, each transform's block step, blocks got back as NumPy."""

    def put(self, block: np.ndarray) -> Any: ...

    def get(self, block: Any) -> np.ndarray: ...

    def step(self, transform: Transform) -> Callable[..., Any]: ...


class _HostSteps:
    """The NumPy block steps on the CPU: each transform's own `_transform_block`."""

    @staticmethod
    def put(block: np.ndarray) -> np.ndarray:
        return block

    @staticmethod
    def get(block: np.ndarray) -> np.ndarray:
        return block

    @staticmethod
    def step(transform: Transform) -> Callable[..., np.ndarray]:
        return transform._transform_block


class _DeviceSteps:
    """The torch block steps on `device`: each transform's own `_transform_block_torch`, blocks moved there and back.

    Each step gets its own `~synthpack.artefacts.torch_blocks.DeviceVolume`, which keeps
    its per-volume tables for the blocks of its pass.
    """

    def __init__(self, device: str) -> None:
        from .torch_blocks import DeviceVolume  # imports torch: only when a device is asked for

        self._volume = functools.partial(DeviceVolume, device)
        self._blocks = self._volume()

    def put(self, block: np.ndarray) -> Any:
        return self._blocks.put(block)

    def get(self, block: Any) -> np.ndarray:
        return self._blocks.get(block)

    def step(self, transform: Transform) -> Callable[..., Any]:
        return functools.partial(_torch_step, transform, self._volume())


def _torch_step(transform: Transform, volume: Any, block: Any, context: BlockContext, **params: Any) -> Any:
    """`transform`'s torch step with its `volume`, called as `_HostSteps`' steps are."""
    return transform._transform_block_torch(block, context, volume, **params)


def _run_pass(
    passed: list[_Step], source: Any, target: Any, seed: int, chunks: tuple[int, int, int], threads: int,
    where: _Where,
) -> None:
    """One pass over the volume: its lead step (with halo or whole slices), then its voxel steps.

    An empty pass copies `source` to `target`. `where` runs the steps: `_HostSteps`, or
    `_DeviceSteps` (blocks moved to a torch device and back).
    """
    shape = tuple(int(n) for n in source.shape)
    head = passed[0] if passed else None
    halo = np.asarray(head.transform.halo(**head.params) if head else (0, 0, 0), dtype=np.int64)
    functions = [where.step(step.transform) for step in passed]

    stored = halo[1:].any() and not isinstance(source, np.ndarray)
    read = _HaloReads(source, halo) if stored else functools.partial(_read_with_halo, source, halo=halo)

    def block(box: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        lo, hi = box
        out = where.put(read(lo, hi))
        origin = tuple(int(v) for v in lo - halo)
        for step, function in zip(passed, functions):
            context = BlockContext(generator(seed, "transform_blocks", step.index, *lo),
                                   stream(seed, "transform_volume", step.index), origin, shape)
            out = function(out, context, **step.params)
            if step is head and halo.any():
                out = out[tuple(slice(int(h), int(h) + int(n)) for h, n in zip(halo, hi - lo))]
                origin = tuple(int(v) for v in lo)
        return where.get(out)

    by_slice = head is not None and head.transform.locality == "slice"
    for (lo, hi), values in bounded_map(block, _blocks(shape, chunks, by_slice), threads):
        target[tuple(slice(a, b) for a, b in zip(lo, hi))] = values


def _without_torch(pipeline: Transform | Compose) -> list[str]:
    """The names of the transforms of `pipeline` without a torch step (empty: it can run on a device)."""
    return [t.name for t in steps(pipeline) if not t.has_torch_step]


def device_for(pipeline: Transform | Compose, device: str | None) -> str | None:
    """The torch device `pipeline` runs on when `apply_blockwise` is asked for `device`.

    `device` itself where every transform has a torch step (`Transform.has_torch_step`),
    else None (NumPy on the CPU).
    """
    return None if device is None or _without_torch(pipeline) else device


def _steps_on(pipeline: Transform | Compose, device: str | None) -> _Where:
    """What runs the steps: `_DeviceSteps` on `device` if every transform has a torch step, else `_HostSteps`."""
    runs_on = device_for(pipeline, device)
    if runs_on is None:
        if device is not None:
            logger.info("post-processing on the CPU, not on %s: no torch version of %s", device,
                        ", ".join(sorted(set(_without_torch(pipeline)))))
        return _HostSteps()
    logger.info("post-processing on %s", runs_on)
    return _DeviceSteps(runs_on)


def apply_blockwise(
    pipeline: Transform | Compose,
    source: Any,
    target: Any,
    seed: int,
    chunks: Sequence[int],
    *,
    threads: int | None = None,
    scratch: Callable[[], Any] | None = None,
    device: str | None = None,
) -> list[dict[str, Any]]:
    """Apply `pipeline` to the volume `source`, block by block, into `target`.

    Parameters
    ----------
    pipeline : Transform or Compose
        The artefacts, applied in order (see the module docstring for how); an
        empty pipeline copies `source` into `target`.
    source : array-like, shape (Z, Y, X)
        Input intensities (NumPy array, memory map or Zarr array); read only.
    target : array-like, shape (Z, Y, X)
        Output, float32 (or any array accepting float32 blocks by slice
        assignment); every voxel is written. Must not be `source`.
    seed : int
        Seed of every draw (non-negative).
    chunks : sequence of 3 int
        Block shape in voxels (``"slice"`` transforms use slabs of whole slices
        holding about as many voxels). Part of what the result depends on.
    threads : int, optional
        Blocks done at once; default: the number of CPU cores.
    scratch : callable, optional
        Returns a new array like `target`, for the intermediate volume of
        pipelines of more than one pass (see the module docstring).
    device : str, optional
        A torch device (``"cuda"``, ``"cuda:1"``, ``"cpu"``) to run the steps on (each
        transform's `~Transform._transform_block_torch`): the same values within float32
        rounding, with the same random draws. A pipeline holding a transform without a
        torch step runs on the CPU as a whole (logged). Default None: NumPy on the CPU.

    Returns
    -------
    list of dict
        The record of what was applied, as `Transform.apply` gives it.

    Raises
    ------
    SynthpackInputError
        If `source` is not 3D, shapes differ, `chunks` is not 3 positive
        integers, or a needed `scratch` is missing.
    """
    if len(source.shape) != 3 or tuple(source.shape) != tuple(target.shape):
        raise SynthpackInputError(
            f"blockwise artefacts need a 3D source and a target of its shape, got {source.shape} and {target.shape}"
        )
    chunks = tuple(int(c) for c in chunks)
    if len(chunks) != 3 or min(chunks) < 1:
        raise SynthpackInputError(f"chunks must be three positive integers (z, y, x), got {chunks}")
    threads = thread_count(threads)
    drawn = _draw(pipeline, seed)
    passes = _passes(drawn) or [[]]
    if len(passes) > 1 and scratch is None:
        raise SynthpackInputError(
            f"this pipeline needs {len(passes)} passes over the volume: give a scratch array factory"
        )
    where = _steps_on(pipeline, device)
    spare = scratch() if len(passes) > 1 else None
    current = source
    for i, passed in enumerate(passes):
        # the last pass writes `target`; earlier ones alternate, so each reads what the one before wrote
        out = target if (len(passes) - 1 - i) % 2 == 0 else spare
        logger.debug("artefact pass %d/%d: %s", i + 1, len(passes),
                     ", ".join(s.transform.name for s in passed) or "copy")
        _run_pass(passed, current, out, seed, chunks, threads, where)
        current = out
    return [s.transform.record_entry(s.params) for s in drawn]
