"""DataLoader collate functions: detection batches as lists, or compact targets as a few tensors."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torchvision import tv_tensors

from ..errors import SynthpackInputError
from .targets import Item

__all__ = ["collate_fn", "collate_stacked"]


def collate_fn(batch: Sequence[Item]) -> tuple[list[tv_tensors.Image], list[dict[str, Any]]]:
    """DataLoader collate for detection batches: ``[(image, target), ...] -> (images, targets)``.

    Images and targets stay lists (instances per slice vary), as torchvision's
    detection models expect.
    """
    return [image for image, _ in batch], [target for _, target in batch]


def _stack(tensors: Sequence[torch.Tensor]) -> torch.Tensor:
    """``torch.stack`` of same-shape tensors, as plain tensors (tv_tensors subclasses dropped)."""
    return torch.stack([tensor.as_subclass(torch.Tensor) for tensor in tensors])


def collate_stacked(batch: Sequence[Item]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """DataLoader collate for compact targets (``dense_masks=False``): five tensors per batch.

    Every slice of the batch must have the same (H, W). Per-instance values are
    concatenated with their batch index (the layout ultralytics uses for its own
    batches), so a batch crosses from a worker to the main process as a handful
    of tensors instead of several per item: the DataLoader moves each tensor a
    worker returns to new shared memory, which costs per tensor as well as per byte.

    Returns
    -------
    images : Tensor, float32, (B, 1, H, W)
    targets : dict
        ``instance_map`` (B, H, W) int32 (the semantic mask is ``instance_map > 0``);
        ``boxes`` (M, 4) float32 XYXY for the M instances of the batch;
        ``instances`` (M, 3) int64 columns ``batch_index, label, instance_id``;
        ``index`` (B, 2) int64 columns ``pack, slice``.
    """
    targets = [target for _, target in batch]
    if any("instance_map" not in target for target in targets):
        raise SynthpackInputError("collate_stacked needs dense_masks=False datasets; use collate_fn otherwise")
    shapes = {tuple(image.shape) for image, _ in batch}
    if len(shapes) != 1:
        raise SynthpackInputError(
            f"collate_stacked needs slices of one shape, got {sorted(shapes)}: use collate_fn for mixed sizes"
        )
    counts = torch.tensor([len(target["labels"]) for target in targets])
    instances = torch.stack([
        torch.repeat_interleave(torch.arange(len(batch)), counts),
        torch.cat([t["labels"] for t in targets]),
        torch.cat([t["instance_ids"] for t in targets]),
    ], dim=1)
    return _stack([image for image, _ in batch]), {
        "instance_map": _stack([t["instance_map"] for t in targets]),
        "boxes": torch.cat([t["boxes"].as_subclass(torch.Tensor) for t in targets]),
        "instances": instances,
        "index": torch.tensor([[t["pack"], t["slice"]] for t in targets], dtype=torch.int64),
    }
