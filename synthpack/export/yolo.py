"""Export packs and labelled real scans as an Ultralytics YOLO instance-segmentation dataset.

Layout of the output folder ``OUT``::

    data.yaml                  path, train, val, test, names {0: particle}; the window in a comment
    export.json                settings, intensity window, sources, counts (also marks OUT as an export)
    images/{train,val,test}/   8-bit grey PNG slices
    labels/{train,val,test}/   one .txt per image: ``0 x1 y1 x2 y2 ...`` per polygon
    truth/test/                16-bit PNG instance images of the test slices, for `synthpack evaluate`

File names, splits and images are those of every 2D export: `YoloWriter` adds the
label files to the slice loop of `synthpack.export.exporter` (the sources, the split of
their slices and the intensity window are planned by `synthpack.export.slices`), so a
YOLO and a COCO export of the same inputs hold the same images in the same splits.

Format decisions
----------------
Intensity window
    One window for every source (see `synthpack.export.slices`), recorded in
    ``data.yaml`` and ``export.json``.
Polygons
    Each instance's section in a slice is split into its 4-connected parts
    (a grain that the slice cuts into several pieces gives several parts), and
    each part is ONE label line: its outer boundary traced by
    `skimage.measure.find_contours` at level 0.5 (along the pixel edges), the
    vertices on straight runs removed (lossless, about 2.4x fewer vertices),
    then moved a quarter pixel inwards. Coordinates are continuous image
    coordinates normalised by the image size: ``x = (column + 0.5) / W``,
    ``y = (row + 0.5) / H``, so the image spans [0, 1]. The quarter-pixel inset
    makes the polygon rasterise back to the part exactly (holes aside) both
    ways it is read: by "pixel centre inside the polygon" (skimage.draw.polygon,
    `rasterize_yolo_labels`) and by Ultralytics' own ``polygon2mask``
    (cv2.fillPoly on truncated vertices, boundary pixels included), which
    widens polygons traced along the pixel edges by one pixel on the right and
    bottom (mean part Dice 0.94 instead of 1.0 on a sample pack's small
    grain sections). At other training resolutions cv2.fillPoly still adds up
    to one resized pixel; no polygon can avoid that at every scale.
    `tolerance` > 0 simplifies the outline with
    `skimage.measure.approximate_polygon`, but its chords cut the corners of
    convex outlines, so masks shrink: on a 150-grain sample pack (sections
    ~10-40 px across; bench/bench_export.py) the mean part Dice falls from
    0.9999 to 0.977, 0.966 and 0.952 (0.991, 0.980 and 0.971 as Ultralytics
    rasterises) at 0.5, 0.75 and 1 px, for label files 1.8x, 2.9x and 3.8x
    smaller. That bias is of the size of the effects the paper measures, so
    the default is exact (0).
Holes
    A polygon cannot encode a hole, so holes inside a part are filled. They are
    rare in grain sections; the filled pixels are counted (``hole_pixels``;
    the Dice of a filled part with ``A`` pixels and ``H`` hole pixels is
    ``2A / (2A + H)``).
Fragments
    Parts smaller than `min_area` pixels get no label line and are counted
    (``dropped_fragments``).
Truth images
    For the splits in `truth_splits` (default test) ``truth/<split>/<name>.png``
    holds the slice's exact instances with the ids of the label lines (line
    ``k`` is id ``k + 1``; dropped fragments follow them), for scoring
    predictions with `synthpack.metrics.evaluate_folders`. The folder is not
    called ``masks``: Ultralytics would take that for semantic masks.

The output folder is built under a temporary name and renamed when complete;
an existing folder is only replaced if it is an earlier export.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
from scipy import ndimage
from skimage.draw import polygon as draw_polygon
from skimage.measure import approximate_polygon, find_contours
from skimage.measure import label as connected_parts

from .. import __version__
from .._shared.schema import default_of, non_negative, setting
from ..errors import SynthpackInputError
from ..io import write_label_image
from ..io.atomic import Output
from ..scan.split import SPLITS
from .exporter import SliceSettings, SliceWriter, run_export
from .slices import MIN_AREA, ExportSlice, ExportSummaryBase, PathLike, RealScan, split_counts

__all__ = [
    "ExportSummary",
    "SlicePolygons",
    "slice_polygons",
    "yolo_label_text",
    "rasterize_yolo_labels",
    "YOLO_OUTPUT",
    "YoloWriter",
    "export_yolo",
]

CLASS_NAMES = {0: "particle"}
_EIGHT = np.ones((3, 3), dtype=bool)
# Polygons run this far (pixels) inside the pixel edges: see "Polygons" in the module docstring.
_INSET = 0.25


# --------------------------------------------------------------------------- #
# Polygons
# --------------------------------------------------------------------------- #


@dataclass
class SlicePolygons:
    """Polygons of one label slice (see `slice_polygons`).

    Attributes
    ----------
    polygons : list of ndarray, shape (K, 2), float64
        Outer boundary of each kept part, a quarter pixel inside the pixel
        edges, vertices ``(row, column)`` in pixel index coordinates (pixel
        centres at integers), not repeated at the end.
    instance_ids : ndarray of int64, shape (len(polygons),)
        Label (instance id in the slice) each polygon belongs to.
    parts : ndarray of int32, shape (H, W)
        Part ids: polygon ``k`` is ``k + 1``, dropped fragments follow; 0 = background.
    dropped_fragments : int
        Parts below the minimum area (no polygon).
    instance_pixels : int
        Pixels of the kept parts.
    hole_pixels : int
        Pixels of holes that the polygons fill.
    """

    polygons: list[np.ndarray]
    instance_ids: np.ndarray
    parts: np.ndarray
    dropped_fragments: int
    instance_pixels: int
    hole_pixels: int


def _outer_contour(mask: np.ndarray) -> tuple[np.ndarray, bool]:
    """Outer boundary (row, col) of a padded 4-connected part, and whether it has holes."""
    contours = find_contours(mask, 0.5)
    if len(contours) == 1:
        return contours[0], False
    areas = [abs(_shoelace(c)) for c in contours]
    return contours[int(np.argmax(areas))], True


def _previous(vertices: np.ndarray) -> np.ndarray:
    return np.concatenate((vertices[-1:], vertices[:-1]))


def _next(vertices: np.ndarray) -> np.ndarray:
    return np.concatenate((vertices[1:], vertices[:1]))


def _shoelace(contour: np.ndarray) -> float:
    """Signed area of a closed polygon of (row, col) vertices."""
    previous = _previous(contour)
    return 0.5 * float(np.dot(contour[:, 0], previous[:, 1]) - np.dot(contour[:, 1], previous[:, 0]))


def _inset(vertices: np.ndarray, distance: float) -> np.ndarray:
    """Move every edge of a closed polygon `distance` inwards (mitred corners, the miter capped at 2x)."""
    before = vertices - _previous(vertices)
    after = _next(vertices) - vertices
    sign = 1.0 if _shoelace(vertices) >= 0 else -1.0
    normals = [sign * np.stack([e[:, 1], -e[:, 0]], axis=1) / np.hypot(e[:, 0], e[:, 1])[:, None]
               for e in (before, after)]
    miter = (normals[0] + normals[1]) / np.maximum(1 + np.sum(normals[0] * normals[1], axis=1), 0.5)[:, None]
    return vertices + distance * miter


def _drop_collinear(vertices: np.ndarray) -> np.ndarray:
    """The vertices of a closed polygon (not repeated at the end) where it turns."""
    before = vertices - _previous(vertices)
    after = _next(vertices) - vertices
    return vertices[before[:, 0] * after[:, 1] != before[:, 1] * after[:, 0]]


def slice_polygons(labels: np.ndarray, *, min_area: int = MIN_AREA, tolerance: float = 0.0) -> SlicePolygons:
    """Polygons of the 4-connected parts of every instance in a label slice.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Instance labels, 0 = background.
    min_area : int
        Parts with fewer pixels get no polygon (counted as dropped fragments).
    tolerance : float
        Simplification tolerance, pixels. 0 (default) keeps the exact outline
        (only vertices on straight runs are removed): the polygon rasterises
        back to the part, holes filled.

    Returns
    -------
    SlicePolygons
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise SynthpackInputError(f"a label slice must be 2D, got shape {labels.shape}")
    parts = connected_parts(labels, background=0, connectivity=1).astype(np.int32, copy=False)
    n_parts = int(parts.max())
    areas = np.bincount(parts.ravel(), minlength=n_parts + 1)
    boxes = ndimage.find_objects(parts)
    polygons, instance_ids, kept, hole_pixels = [], [], [], 0
    for part_id, box in enumerate(boxes, start=1):
        if areas[part_id] < min_area:
            continue
        mask = np.pad(parts[box] == part_id, 1)
        contour, has_holes = _outer_contour(mask.astype(np.float32))
        if has_holes:
            hole_pixels += int(np.count_nonzero(ndimage.binary_fill_holes(mask, structure=_EIGHT) & ~mask))
        vertices = _drop_collinear(approximate_polygon(contour, tolerance)[:-1] if tolerance else contour[:-1])
        if len(vertices) < 3:  # simplified away: keep the exact outline
            vertices = _drop_collinear(contour[:-1])
        polygons.append(_inset(vertices, _INSET) + (box[0].start - 1, box[1].start - 1))
        instance_ids.append(int(labels[box][mask[1:-1, 1:-1]][0]))
        kept.append(part_id)
    kept_ids = np.array(kept, dtype=np.int64)
    dropped = np.setdiff1d(np.arange(1, n_parts + 1), kept_ids)
    lookup = np.zeros(n_parts + 1, dtype=np.int32)
    lookup[kept_ids] = np.arange(1, len(kept_ids) + 1)
    lookup[dropped] = np.arange(len(kept_ids) + 1, n_parts + 1)
    return SlicePolygons(polygons, np.array(instance_ids, dtype=np.int64), lookup[parts], len(dropped),
                         int(areas[kept_ids].sum()), hole_pixels)


def yolo_label_text(polygons: Sequence[np.ndarray], shape: tuple[int, int], class_id: int = 0) -> str:
    """Ultralytics segment label lines ``class x1 y1 x2 y2 ...`` for (row, col) pixel polygons.

    Coordinates are ``x = (col + 0.5) / W``, ``y = (row + 0.5) / H`` with 6 decimals.
    """
    height, width = shape
    lines = []
    for vertices in polygons:
        xy = np.empty((len(vertices), 2))
        xy[:, 0] = (vertices[:, 1] + 0.5) / width
        xy[:, 1] = (vertices[:, 0] + 0.5) / height
        lines.append(f"{class_id} " + " ".join(f"{v:.6f}" for v in np.clip(xy, 0, 1).ravel()))
    return "".join(line + "\n" for line in lines)


def rasterize_yolo_labels(text: str, shape: tuple[int, int]) -> list[np.ndarray]:
    """Masks of the polygons of YOLO segment label text (the inverse of `yolo_label_text`).

    Parameters
    ----------
    text : str
        Contents of a label file: ``class x1 y1 x2 y2 ...`` per line.
    shape : (H, W)
        Image shape in pixels.

    Returns
    -------
    list of ndarray of bool, shape (H, W)
        One per line: the pixels whose centres lie inside the polygon.
    """
    height, width = shape
    masks = []
    for line in text.splitlines():
        if not line.strip():
            continue
        values = np.array(line.split()[1:], dtype=np.float64).reshape(-1, 2)
        mask = np.zeros(shape, dtype=bool)
        rows, cols = draw_polygon(values[:, 1] * height - 0.5, values[:, 0] * width - 0.5, shape)
        mask[rows, cols] = True
        masks.append(mask)
    return masks


# --------------------------------------------------------------------------- #
# Export
# --------------------------------------------------------------------------- #


@dataclass
class ExportSummary(ExportSummaryBase):
    """What `export_yolo` wrote.

    Attributes
    ----------
    out, window, window_from, images, sources, settings
        As in `synthpack.export.slices.ExportSummaryBase`.
    instances, empty_images, dropped_fragments, instance_pixels, hole_pixels : dict
        Per split (``train``, ``val``, ``test``): label lines, images without
        any label line, parts too small for a label line, pixels of the
        labelled parts, and hole pixels filled by polygons.
    """

    instances: dict[str, int] = field(default_factory=split_counts)
    empty_images: dict[str, int] = field(default_factory=split_counts)
    dropped_fragments: dict[str, int] = field(default_factory=split_counts)
    instance_pixels: dict[str, int] = field(default_factory=split_counts)
    hole_pixels: dict[str, int] = field(default_factory=split_counts)

    FORMAT: ClassVar[str] = "synthpack-yolo-seg"
    COUNTS: ClassVar[tuple[str, ...]] = ("images", "instances", "empty_images", "dropped_fragments",
                                         "instance_pixels", "hole_pixels")


#: A YOLO dataset folder: an earlier export (``export.json``) is replaced, anything else is refused.
YOLO_OUTPUT = Output("YOLO dataset", marker="export.json")


def _known_splits(splits: Sequence[str]) -> bool:
    """splits among train, val and test"""
    return set(splits) <= set(SPLITS)


@dataclass
class YoloWriter(SliceWriter):
    """The YOLO format's hooks of the slice exporter (`synthpack.export.exporter`): label files and ``data.yaml``.

    Attributes
    ----------
    tolerance : float
        Polygon simplification tolerance, pixels; 0 = exact outlines (see the module docstring).
    truth_splits : sequence of str
        Splits for which ``truth/<split>/`` instance images are written.
    """

    tolerance: float = setting(0.0, non_negative, "polygon simplification in pixels (0: exact outlines)")
    truth_splits: Sequence[str] = setting(("test",), _known_splits,
                                          "splits that also get truth/ instance images for `evaluate`")

    OUTPUT: ClassVar[Output] = YOLO_OUTPUT
    SUMMARY: ClassVar[type[ExportSummaryBase]] = ExportSummary

    def record(self) -> dict:
        return {"tolerance": self.tolerance, "truth_splits": list(self.truth_splits), "class_names": CLASS_NAMES}

    def start(self, staging: Path) -> None:
        for sub, splits in (("labels", SPLITS), ("truth", self.truth_splits)):
            for s in splits:
                (staging / sub / s).mkdir(parents=True)

    def write_slice(self, staging: Path, item: ExportSlice, settings: SliceSettings) -> dict[str, int]:
        """Write the label lines of one slice and, for a truth split, its truth image; return its counts."""
        result = slice_polygons(item.labels, min_area=settings.min_area, tolerance=self.tolerance)
        (staging / "labels" / item.split / f"{item.stem}.txt").write_text(yolo_label_text(result.polygons,
                                                                                          item.labels.shape))
        if item.split in self.truth_splits:
            write_label_image(staging / "truth" / item.split / item.stem, result.parts)
        return {"instances": len(result.polygons), "empty_images": int(not result.polygons),
                "dropped_fragments": result.dropped_fragments, "instance_pixels": result.instance_pixels,
                "hole_pixels": result.hole_pixels}

    def dataset_files(self, out: Path, summary: ExportSummary) -> Iterator[tuple[str, str]]:
        """``data.yaml``: the dataset's folder, splits and class names; the window in a comment."""
        lo, hi = summary.window
        yield "data.yaml", (
            f"# synthpack {__version__} YOLO instance-segmentation export; details in export.json\n"
            f"# intensity window [{lo:.6g}, {hi:.6g}] ({summary.window_from}):\n"
            "#   pixel = round(255 * clip((value - lo) / (hi - lo), 0, 1))\n"
            "# moved the folder? edit `path`, or delete it (Ultralytics then uses this file's folder)\n"
            f"path: {json.dumps(str(out.resolve()))}\n"
            "train: images/train\nval: images/val\ntest: images/test\n"
            "names:\n" + "".join(f"  {k}: {v}\n" for k, v in CLASS_NAMES.items())
        )


def export_yolo(
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
    tolerance: float = default_of(YoloWriter, "tolerance"),
    truth_splits: Sequence[str] = default_of(YoloWriter, "truth_splits"),
    progress: bool = True,
    overwrite: bool = False,
) -> ExportSummary:
    """Write packs and real scans as a YOLO segmentation dataset (layout and format: module docstring).

    Parameters
    ----------
    out : path-like
        Output folder; must be new, empty or an earlier export (replaced), or
        any folder with `overwrite` (the export's files are written into it and
        its other files are kept).
    packs : sequence of path-like
        Pack folders, or folders holding pack folders (``pack_0000``, ...).
    real : sequence of Scan or (tomogram, labels) path pairs
        Labelled real scans (read with `synthpack.io.read_scan`).
    axis, split, val_fraction, postprocess, window
        The slicing settings (`synthpack.export.exporter.SliceSettings`): slicing
        axis; ``"paper"`` (every volume gives train, val and test slices) or
        ``"real-test"`` (synthetic packs give training slices only); validation
        fraction of each split volume's slices, next to the test block; synthetic
        images from the post-processed ``tomogram`` (True) or the ``clean`` volume;
        intensity window (default: 0.5/99.5 percentiles of the real tomograms, else
        of the first pack's clean volume).
    min_area : int
        Parts of fewer pixels get no label line.
    tolerance : float
        Polygon simplification tolerance, pixels; 0 = exact outlines (see the module docstring).
    truth_splits : sequence of str
        Splits for which ``truth/<split>/`` instance images are written.
    progress : bool
        Show a progress bar.
    overwrite : bool
        Write into a folder that holds something other than an earlier export.

    Returns
    -------
    ExportSummary
    """
    settings = SliceSettings(axis=axis, split=split, val_fraction=val_fraction, postprocess=postprocess,
                             window=window, min_area=min_area)
    return run_export(YoloWriter(tolerance=tolerance, truth_splits=truth_splits), out, packs, real, settings,
                      progress=progress, overwrite=overwrite)
