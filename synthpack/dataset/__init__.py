"""PyTorch datasets of 2D slices and 3D patches of synthetic packs and of real scans (paper section 4.1).

`SyntheticParticlePackDataset` builds synthetic packs from a source (a built-in
sample scan, a labelled scan on disk or a particle library), caches them under a
root directory and serves their slices along one axis; `ScanSliceDataset` serves
the slices of a real labelled scan the same way, so that real and synthetic data
concatenate with `torch.utils.data.ConcatDataset`.

Item format (both datasets), following torchvision's detection conventions::

    image, target = dataset[i]
    image                   tv_tensors.Image, float32, shape (1, H, W)
    target["masks"]         tv_tensors.Mask, bool, shape (N, H, W), one per instance in the slice
                            (with dense_masks=False: target["instance_map"], Mask, int32,
                            (H, W), instance j as j + 1; expand_masks(target) gives "masks")
    target["boxes"]         tv_tensors.BoundingBoxes, float32, (N, 4), XYXY, canvas_size (H, W)
    target["labels"]        int64, (N,), class ids: all 1 (particle)
    target["instance_ids"]  int64, (N,), the instances' values in the label volume
    target["semantic"]      tv_tensors.Mask, uint8, (H, W): 1 = particle, 0 = pore, tube, outside
    target["pack"]          int, pack index (0 for a real scan)
    target["slice"]         int, slice index along `axis` in the volume

Slicing along axis 0 gives (H, W) = (Y, X), along axis 1 (Z, X), along axis 2
(Z, Y). Boxes are in pixel-edge coordinates: a mask covering columns 3..7 has
``x1 = 3, x2 = 8`` (torchvision.ops.masks_to_boxes gives the inclusive ``x2 = 7``),
so that flips and crops by torchvision v2 transforms keep boxes and masks
consistent. Instances are ordered by increasing instance id.

Split: the slices of each volume along `axis` are split with
`synthpack.scan.split.split_slices` (the central 20% are ``"test"``, the rest
``"train"``), so no test slice has a near-identical neighbour in the training set.

Transform order in ``__getitem__``:

1. read the image and label slices with `synthpack.io.read_slice` (only those
   slices: from memory-mapped TIFF files, or only the chunks of a Zarr pack that
   the slice crosses);
2. apply the artefact transforms (`synthpack.artefacts`) to the float32 slice as a
   NumPy array, with a generator seeded by ``(seed, epoch, pack, axis, slice)``:
   fresh noise every epoch (see ``set_epoch``), the same noise for the same epoch
   in any process, with any number of DataLoader workers;
3. build the image tensor and target dict;
4. apply the other transforms as ``image, target = transform(image, target)``
   (torchvision v2 transforms and any callable of that form), in order.

DataLoader workers: datasets hold paths and small index arrays only; every
process opens the volumes (memory maps) on its first item and keeps them, so
nothing big is pickled and ``persistent_workers=True`` works. The DataLoader
moves each tensor a worker returns to new shared memory (one copy per tensor),
so fewer, smaller tensors cross faster: ``dense_masks=False`` items with
`collate_stacked` cross as five tensors per batch. Use `collate_fn` for
detection-style batches (the number of instances varies per slice).

3D patches: `PatchDataset` serves random or grid (D, H, W) patches of the
volumes of either dataset (or of a scan), with the same split along `axis` (every
patch inside one block of its split) and seeded artefact transforms, as
MONAI / TorchIO dict items; `synthpack.dataset.patches` documents its format.

Modules
-------
``base``        `SliceDataset`: split, index, epoch, item assembly, ``repr``
``synthetic``   `SyntheticParticlePackDataset`
``real``        `ScanSliceDataset`
``patches``     `PatchDataset`: 3D patches of either's volumes
``source``      what packs are made from: sample, scan files or library
``cache``       the pack cache: content-hash key, check and build (the "download")
``targets``     image tensor and detection target of one slice; `expand_masks`
``transforms``  artefact transforms on the slice, then ``(image, target)`` callables
``collate``     `collate_fn`, `collate_stacked`
"""

from .collate import collate_fn, collate_stacked
from .patches import PAD_LABEL, PatchDataset
from .real import ScanSliceDataset
from .source import SAMPLE_SEED
from .synthetic import SyntheticParticlePackDataset
from .targets import Item, expand_masks, instance_target

__all__ = [
    "SyntheticParticlePackDataset",
    "ScanSliceDataset",
    "PatchDataset",
    "PAD_LABEL",
    "instance_target",
    "expand_masks",
    "collate_fn",
    "collate_stacked",
    "Item",
    "SAMPLE_SEED",
]
