"""Export packs and labelled real scans as a COCO instance-segmentation dataset.

Layout of the output folder ``OUT``::

    coco_export.json                     settings, intensity window, sources, counts (marks OUT as an export)
    images/{train,val,test}/             8-bit grey PNG slices
    annotations/instances_{train,val,test}.json   COCO annotations of each split's images

The images, their names and their splits are those of the YOLO export of the same
inputs and settings (`CocoWriter` adds the annotations to the slice loop of
`synthpack.export.exporter`, as `YoloWriter` adds its label files), so the two
formats can be compared on the same slices. Read a split with
``pycocotools.coco.COCO("OUT/annotations/instances_train.json")``, its images
under ``OUT/images/train`` (for Detectron2: ``register_coco_instances(name, {},
json_file, image_root)``).

Format decisions
----------------
Instances
    ONE annotation per label value present in a slice: a grain that the slice
    cuts into several pieces is one annotation whose mask holds all the pieces,
    and holes stay holes. This is the instance of the label volume, and what COCO
    means by an object; the YOLO export instead writes one polygon per piece
    (a polygon can hold neither holes nor several pieces).
Masks
    ``segmentation`` is compressed RLE (``{"size": [H, W], "counts": str}``,
    column-major runs as `pycocotools.mask` encodes them): exact, so
    ``COCO.annToMask`` gives back the label slice's pixels of the instance, bit
    for bit. ``area`` is the instance's pixel count and ``bbox`` its
    ``[x, y, width, height]`` in pixels (``pycocotools.mask.area`` and
    ``toBbox`` of the mask); ``iscrowd`` is 0. ``instance_label`` (not a COCO
    key; loaders ignore it) is the label value in the source volume, so one
    grain can be followed across slices.
Small instances
    Instances with fewer than `min_area` pixels in a slice (a grain's tip) get
    no annotation and are counted (``dropped_instances``).
Empty slices
    A slice without instances is kept as an image with no annotations (a
    background example, as in the YOLO export).
Ids
    Image and annotation ids are numbered from 1 across the whole export (in
    source and slice order), so they stay unique if the splits are merged. The
    one category is ``{"id": 1, "name": "particle"}``.
Intensity window
    One window for every source (see `synthpack.export.slices`), recorded in
    ``coco_export.json`` and in each annotation file's ``info``.

The output folder is built under a temporary name and renamed when complete;
an existing folder is only replaced if it is an earlier COCO export.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from itertools import count
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .. import __version__
from .._shared.schema import default_of
from .._shared.strict_json import dumps as strict_json
from ..errors import SynthpackInputError
from ..io.atomic import Output
from ..scan.split import SPLITS
from .exporter import SliceSettings, SliceWriter, run_export
from .slices import MIN_AREA, ExportSlice, ExportSummaryBase, PathLike, RealScan, split_counts

__all__ = ["CATEGORIES", "COCO_OUTPUT", "CocoExportSummary", "CocoWriter", "instance_annotations", "export_coco"]

#: The COCO categories: every instance is a particle.
CATEGORIES = [{"id": 1, "name": "particle", "supercategory": "particle"}]

#: A COCO dataset folder: an earlier export (``coco_export.json``) is replaced, anything else is refused.
COCO_OUTPUT = Output("COCO dataset", marker="coco_export.json")


def _mask_module() -> Any:
    """`pycocotools.mask`, or a one-line error saying how to install it."""
    try:
        return importlib.import_module("pycocotools.mask")
    except ImportError as exc:
        raise SynthpackInputError('the COCO export needs the Python package pycocotools, which is not installed: '
                                  'pip install "synthpack[coco]" (or pip install pycocotools)') from exc


def instance_annotations(labels: np.ndarray, *, min_area: int = MIN_AREA) -> tuple[list[dict], int]:
    """COCO annotations (without ids) of every instance of a label slice, and how many were too small.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Instance labels, 0 = background.
    min_area : int
        Instances with fewer pixels get no annotation.

    Returns
    -------
    annotations : list of dict
        One per label value with at least `min_area` pixels, in increasing
        label order: ``segmentation`` (compressed RLE), ``area``, ``bbox``,
        ``iscrowd`` (0), ``category_id`` (1) and ``instance_label``.
    dropped : int
        Instances below `min_area`.

    Notes
    -----
    The runs are found from the labelled pixels alone (sorted by label, in
    column-major order), not from one full-size mask per instance, so a slice
    costs O(labelled pixels), whatever its number of instances.
    """
    mask_utils = _mask_module()
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise SynthpackInputError(f"a label slice must be 2D, got shape {labels.shape}")
    height, width = labels.shape
    flat = labels.ravel(order="F")  # COCO's RLE runs down the columns
    where = np.flatnonzero(flat)
    order = np.argsort(flat[where], kind="stable")  # by label; each label's pixels stay in column-major order
    where = where[order]
    values, firsts, sizes = np.unique(flat[where], return_index=True, return_counts=True)
    annotations, dropped = [], 0
    for value, first, size in zip(values.tolist(), firsts.tolist(), sizes.tolist()):
        if size < min_area:
            dropped += 1
            continue
        pixels = where[first:first + size]
        breaks = np.flatnonzero(np.diff(pixels) != 1) + 1
        starts, ends = pixels[np.r_[0, breaks]], pixels[np.r_[breaks - 1, size - 1]] + 1
        # uncompressed RLE: zeros, ones, zeros, ... up to H * W, then compressed by pycocotools
        counts = np.diff(np.r_[0, np.column_stack([starts, ends]).ravel(), height * width])
        rle = mask_utils.frPyObjects({"size": [height, width], "counts": counts.tolist()}, height, width)
        annotations.append({
            "segmentation": {"size": [height, width], "counts": rle["counts"].decode("ascii")},
            "area": int(mask_utils.area(rle)), "bbox": [float(v) for v in mask_utils.toBbox(rle)],
            "iscrowd": 0, "category_id": CATEGORIES[0]["id"], "instance_label": int(value),
        })
    return annotations, dropped


@dataclass
class CocoExportSummary(ExportSummaryBase):
    """What `export_coco` wrote.

    Attributes
    ----------
    out, window, window_from, images, sources, settings
        As in `synthpack.export.slices.ExportSummaryBase`.
    annotations, empty_images, dropped_instances, instance_pixels : dict
        Per split (``train``, ``val``, ``test``): annotations, images without
        any, instances too small for one, and pixels of the annotated instances.
    """

    annotations: dict[str, int] = field(default_factory=split_counts)
    empty_images: dict[str, int] = field(default_factory=split_counts)
    dropped_instances: dict[str, int] = field(default_factory=split_counts)
    instance_pixels: dict[str, int] = field(default_factory=split_counts)

    FORMAT: ClassVar[str] = "synthpack-coco-instances"
    COUNTS: ClassVar[tuple[str, ...]] = ("images", "annotations", "empty_images", "dropped_instances",
                                         "instance_pixels")


def _per_split() -> dict[str, list]:
    return {s: [] for s in SPLITS}


@dataclass
class CocoWriter(SliceWriter):
    """The COCO format's hooks of the slice exporter (`synthpack.export.exporter`): one annotation file per split.

    It keeps each split's image and annotation records until the split's
    ``annotations/instances_<split>.json`` is written (`dataset_files`).
    """

    images: dict[str, list] = field(default_factory=_per_split, init=False, repr=False)
    annotations: dict[str, list] = field(default_factory=_per_split, init=False, repr=False)
    image_ids: Iterator[int] = field(default_factory=lambda: count(1), init=False, repr=False)
    annotation_ids: Iterator[int] = field(default_factory=lambda: count(1), init=False, repr=False)

    OUTPUT: ClassVar[Output] = COCO_OUTPUT
    SUMMARY: ClassVar[type[ExportSummaryBase]] = CocoExportSummary

    def check(self, out: Path) -> None:
        """Refuse to start without pycocotools (saying how to install it)."""
        _mask_module()

    def record(self) -> dict:
        return {"categories": CATEGORIES}

    def write_slice(self, staging: Path, item: ExportSlice, settings: SliceSettings) -> dict[str, int]:
        """Add the slice's image record and the annotations of its instances to its split's; return its counts."""
        height, width = item.labels.shape
        image_id = next(self.image_ids)
        self.images[item.split].append({"id": image_id, "file_name": f"{item.stem}.png", "height": height,
                                        "width": width})
        annotations, dropped = instance_annotations(item.labels, min_area=settings.min_area)
        self.annotations[item.split] += [{"id": next(self.annotation_ids), "image_id": image_id, **annotation}
                                         for annotation in annotations]
        return {"annotations": len(annotations), "empty_images": int(not annotations), "dropped_instances": dropped,
                "instance_pixels": sum(a["area"] for a in annotations)}

    def dataset_files(self, out: Path, summary: CocoExportSummary) -> Iterator[tuple[str, str]]:
        """``annotations/instances_<split>.json`` of each split, its ``info`` naming synthpack and the window."""
        lo, hi = summary.window
        for split in SPLITS:
            info = {"description": f"synthpack {__version__} COCO instance-segmentation export, {split} split; "
                                   "details in coco_export.json",
                    "version": __version__, "contributor": "synthpack", "split": split,
                    "intensity_window": [lo, hi], "intensity_window_from": summary.window_from,
                    "pixel": "round(255 * clip((value - lo) / (hi - lo), 0, 1))"}
            yield f"annotations/instances_{split}.json", strict_json({
                "info": info, "licenses": [], "images": self.images[split], "annotations": self.annotations[split],
                "categories": CATEGORIES})


def export_coco(
    out: PathLike,
    packs: Sequence[PathLike] = (),
    real: Sequence[RealScan] = (),
    *,
    axis: int = default_of(SliceSettings, "axis"),
    split: str = default_of(SliceSettings, "split"),
    val_fraction: float = default_of(SliceSettings, "val_fraction"),
    postprocess: bool = default_of(SliceSettings, "postprocess"),
    window: tuple[float, float] | None = default_of(SliceSettings, "window"),
    min_area: int = default_of(SliceSettings, "min_area"),
    progress: bool = True,
    overwrite: bool = False,
) -> CocoExportSummary:
    """Write packs and real scans as a COCO instance-segmentation dataset (layout and format: module docstring).

    Parameters
    ----------
    out : path-like
        Output folder; must be new, empty or an earlier COCO export (replaced),
        or any folder with `overwrite` (the export's files are written into it
        and its other files are kept).
    packs, real, axis, split, val_fraction, postprocess, window
        As in `synthpack.export.export_yolo`: the same inputs and settings give
        the same images in the same splits.
    min_area : int
        Instances of fewer pixels in a slice get no annotation.
    progress : bool
        Show a progress bar.
    overwrite : bool
        Write into a folder that holds something other than an earlier COCO export.

    Returns
    -------
    CocoExportSummary
    """
    settings = SliceSettings(axis=axis, split=split, val_fraction=val_fraction, postprocess=postprocess,
                             window=window, min_area=min_area)
    return run_export(CocoWriter(), out, packs, real, settings, progress=progress, overwrite=overwrite)
