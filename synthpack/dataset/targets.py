"""Tensors of one item: the image tensor and the detection target of a labelled slice."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from scipy import ndimage
from torchvision import tv_tensors

__all__ = ["Item", "image_tensor", "instance_target", "expand_masks"]

#: One dataset item: ``(image, target)``.
Item = tuple[tv_tensors.Image, dict[str, Any]]


def _zeros(shape: tuple[int, ...], dtype: torch.dtype, shared: bool) -> torch.Tensor:
    """A CPU tensor of zeros of `dtype`; with `shared`, in shared memory.

    ``np.zeros`` maps zero pages, so only the pages written later cost anything;
    `torch.Tensor.share_memory_` then copies them into new shared memory.
    """
    tensor = torch.from_numpy(np.zeros(shape, dtype=torch.empty(0, dtype=dtype).numpy().dtype))
    return tensor.share_memory_() if shared else tensor


def image_tensor(image: np.ndarray) -> tv_tensors.Image:
    """The item image: a (1, H, W) float32 copy of the (H, W) slice `image`."""
    tensor = _zeros((1, *image.shape), torch.float32, shared=False)
    np.copyto(tensor.numpy()[0], image, casting="unsafe")
    return tv_tensors.Image(tensor)


def instance_target(labels: np.ndarray, *, shared: bool = False, dense_masks: bool = True) -> dict[str, Any]:
    """Detection target of one labelled slice.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Instance labels, 0 = background.
    shared : bool
        Put masks (or instance map) and semantic map in shared memory
        (`torch.Tensor.share_memory_`). Not needed in a DataLoader worker: the
        DataLoader moves what a worker returns to shared memory itself.
    dense_masks : bool
        True: ``masks`` holds one (H, W) plane per instance. False: instead
        ``instance_map`` (Mask, int32, (H, W)) holds instance ``j`` as value
        ``j + 1``; it is N times smaller to send from a DataLoader worker, and
        :func:`expand_masks` makes the planes where they are needed (e.g. on the GPU).

    Returns
    -------
    dict
        ``masks`` (Mask, bool, (N, H, W)) or ``instance_map``, ``boxes``
        (BoundingBoxes, float32, (N, 4), XYXY pixel edges), ``labels`` (int64
        ones, (N,)), ``instance_ids`` (int64, (N,), increasing) and ``semantic``
        (Mask, uint8, (H, W)).
    """
    labels = np.asarray(labels)
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    ids = np.flatnonzero(counts)
    # compact labels 1..N, so masks and boxes cost O(H*W) whatever the largest label is
    lookup = np.zeros(counts.size, dtype=np.int32)
    lookup[ids] = np.arange(1, ids.size + 1, dtype=np.int32)
    if dense_masks:
        compact = lookup[labels]
        masks = _zeros((ids.size, *labels.shape), torch.bool, shared)
        planes = masks.numpy()
    else:
        instance_map = _zeros(labels.shape, torch.int32, shared)
        compact = np.take(lookup, labels, out=instance_map.numpy(), mode="clip")  # in range: no check
    semantic = _zeros(labels.shape, torch.uint8, shared)
    np.greater(compact, 0, out=semantic.numpy().view(bool))
    boxes = np.zeros((ids.size, 4), dtype=np.float32)
    for j, (rows, cols) in enumerate(ndimage.find_objects(compact)):
        if dense_masks:
            np.equal(compact[rows, cols], j + 1, out=planes[j, rows, cols])
        boxes[j] = (cols.start, rows.start, cols.stop, rows.stop)
    return {
        ("masks" if dense_masks else "instance_map"): tv_tensors.Mask(masks if dense_masks else instance_map),
        "boxes": tv_tensors.BoundingBoxes(torch.from_numpy(boxes), format="XYXY", canvas_size=labels.shape),
        "labels": torch.ones(ids.size, dtype=torch.int64),
        "instance_ids": torch.from_numpy(ids.astype(np.int64)),
        "semantic": tv_tensors.Mask(semantic),
    }


def expand_masks(target: dict[str, Any]) -> dict[str, Any]:
    """Replace a compact ``instance_map`` (``dense_masks=False``) by the ``masks`` planes.

    Works on any device: ``masks[j] = instance_map == j + 1``, bool, (N, H, W).
    Returns a new dict; a target that already has ``masks`` is returned unchanged.
    """
    if "instance_map" not in target:
        return target
    expanded = {key: value for key, value in target.items() if key != "instance_map"}
    instance_map = target["instance_map"].as_subclass(torch.Tensor)
    values = torch.arange(1, len(target["labels"]) + 1, device=instance_map.device, dtype=instance_map.dtype)
    expanded["masks"] = tv_tensors.Mask(instance_map[None] == values[:, None, None])
    return expanded
