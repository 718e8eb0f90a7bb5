"""The part every dataset export shares: sources, splits, intensity window and PNG slices.

A 2D export (`synthpack.export.yolo`, `synthpack.export.coco`) turns synthetic packs and
labelled real scans into 2D slices along one axis: `plan_slices` opens the sources and
chooses the split of each one's slices and the intensity window, and
`SlicedVolumes.write_images` writes the 8-bit images and hands each slice's labels to the
format's own writer (the slice loop of `synthpack.export.exporter.SliceWriter`). So two
exports of the same inputs with the same settings hold the same images under the same
names in the same splits, whatever their format. A 3D export (`synthpack.export.nnunet`)
opens the same sources with `open_sources`.

Names
    Images are ``images/<split>/<source>_a<axis>_s<slice:04d>.png`` where ``<source>``
    is ``syn_<pack folder name>`` for a synthetic pack and ``real_<tomogram file stem>``
    for a real scan (``-2``, ``-3``... appended if two sources share a name).
Intensity window
    Slices are mapped to 8 bits by ``round(255 * clip((v - lo) / (hi - lo), 0, 1))``
    with ONE window for every source, so that real and synthetic slices of one
    material look alike: by default the 0.5 and 99.5 percentiles of the real
    scans' tomograms (pooled), or, without real scans, of the first pack's
    clean (not post-processed) volume, so that exports with and without
    post-processing share the window. Pass `window` to fix it.
Splits
    Along the slicing axis, each volume's slices are split into train, val
    and test by `synthpack.scan.split.slice_splits`: the paper's central 20% is the
    test set and the val slices are the training slices nearest it on both
    sides. With ``split="real-test"`` synthetic packs give training slices
    only (all of them), so val and test hold real slices only (the paper's
    experiment: train on real + synthetic, test on real).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from PIL import Image

from .. import __version__
from .._shared.console import progress_bar
from ..errors import SynthpackInputError
from .._shared.windows import intensity_window
from ..io import read_scan, read_slice
from ..store.pack import Pack, find_packs, open_pack
from ..scan.core import Scan
from ..scan.split import SPLITS, slice_splits

__all__ = [
    "SPLIT_MODES", "MIN_AREA", "PathLike", "RealScan", "to_uint8", "Source", "open_sources", "ExportSlice",
    "SlicedVolumes", "plan_slices", "ExportSummaryBase", "split_counts",
]

#: ``"paper"``: every volume split train/val/test; ``"real-test"``: synthetic packs train only.
SPLIT_MODES = ("paper", "real-test")
#: Default of the exports' `min_area`: smaller sections (YOLO: parts, COCO: instances) get no label, pixels.
MIN_AREA = 10

#: A path an export takes (a pack folder, a folder of packs, a scan file).
PathLike = str | os.PathLike
#: A labelled real scan an export takes: a `Scan`, or the paths of its tomogram and label volume.
RealScan = Scan | tuple[PathLike, PathLike]


def to_uint8(image: np.ndarray, window: tuple[float, float]) -> np.ndarray:
    """``round(255 * clip((image - lo) / (hi - lo), 0, 1))`` as uint8, same shape."""
    lo, hi = window
    scaled = (np.asarray(image, dtype=np.float32) - np.float32(lo)) * np.float32(255.0 / (hi - lo))
    return np.rint(np.clip(scaled, 0, 255)).astype(np.uint8)


# --------------------------------------------------------------------------- #
# Sources
# --------------------------------------------------------------------------- #


@dataclass
class Source:
    """One volume to export: file-name prefix, origin, image and label volumes, shape (Z, Y, X), and voxel size.

    ``voxel_size`` is ``(dz, dy, dx)`` in ``unit``: a pack's, a `Scan`'s, or a real scan
    file's metadata when `open_sources` is asked for it (else 1.0 px: slices need none).
    """

    name: str
    kind: str  # "real" or "synthetic"
    path: str
    volume: str  # which volume the images come from
    tomogram: Any
    labels: Any
    voxel_size: tuple[float, float, float] = (1.0, 1.0, 1.0)
    unit: str = "px"

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.labels.shape)  # type: ignore[return-value]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-") or "scan"


def _pack_source(pack: Pack, postprocess: bool) -> Source:
    """A synthetic pack's images (post-processed tomogram or clean volume) and labels."""
    volume = "tomogram" if postprocess else "clean"
    return Source(f"syn_{_safe(pack.path.name)}", "synthetic", str(pack.path), volume, getattr(pack, volume),
                  pack.labels, pack.voxel_size, pack.unit)


def _real_source(item: Scan | tuple, index: int, voxel_size: bool) -> Source:
    """A real scan, given as a `Scan` or read from a ``(tomogram, labels)`` pair of paths.

    `voxel_size`: the export needs the files' voxel size (a missing one is warned of);
    else their metadata's is kept where they record one, and they are read in pixels
    without a warning where they do not.
    """
    if isinstance(item, Scan):
        return Source(f"real_scan{index}", "real", item.source, "tomogram", item.tomogram, item.labels,
                      item.voxel_size, item.unit)
    if not (isinstance(item, (tuple, list)) and len(item) == 2):
        raise SynthpackInputError(f"a real scan is a Scan or a (tomogram, labels) pair of paths, got {item!r}")
    tomogram, labels = (Path(p) for p in item)
    scan = read_scan(tomogram, labels, need_voxel_size=voxel_size)
    name = tomogram.name[: -len(".zarr")] if tomogram.name.endswith(".zarr") else tomogram.stem
    return Source(f"real_{_safe(name)}", "real", f"{tomogram} + {labels}", "tomogram", scan.tomogram, scan.labels,
                  scan.voxel_size, scan.unit)


def _unique_names(sources: list[Source]) -> None:
    seen: dict[str, int] = {}
    for source in sources:
        count = seen.get(source.name, 0) + 1
        seen[source.name] = count
        if count > 1:
            source.name = f"{source.name}-{count}"


def open_sources(
    packs: Sequence[PathLike],
    real: Sequence[RealScan],
    *,
    postprocess: bool,
    voxel_size: bool = False,
) -> tuple[list[Source], list[Pack]]:
    """Open the packs (verified) and the real scans of an export.

    Parameters
    ----------
    packs, real, postprocess
        As in `synthpack.export.export_yolo`.
    voxel_size : bool
        Whether the export needs the real scan files' voxel size (a 3D export): one
        they do not record is then warned of; else they are read in pixels (1.0 px)
        without a warning where they record none (the voxel size read is logged, and
        kept with the source, either way).

    Returns
    -------
    sources : list of Source
        Packs first, then real scans, with unique names.
    opened : list of Pack
        The packs, in the sources' order.

    Raises
    ------
    SynthpackInputError
        When a pack or scan cannot be read.
    """
    for path in packs:
        if Path(path).is_file():
            raise SynthpackInputError(f"{path} is a file, not a pack folder: give pack folders made by "
                                      "`synthpack generate`, or folders holding them")
    opened = [open_pack(directory, verify=True) for path in packs for directory in find_packs(path)]
    sources = [_pack_source(pack, postprocess) for pack in opened]
    sources += [_real_source(item, k, voxel_size) for k, item in enumerate(real)]
    _unique_names(sources)
    return sources, opened


def _choose_window(window: tuple[float, float] | None, reals: list[Source],
                   packs: list[Pack]) -> tuple[tuple[float, float], str]:
    """The intensity window ``(lo, hi)`` and where it came from (see "Intensity window" in the module docstring)."""
    if window is not None:
        lo, hi = (float(v) for v in window)  # checked by `SliceSettings.check`
        return (lo, hi), "given"
    if reals:
        return intensity_window([s.tomogram for s in reals]), "0.5/99.5 percentiles of the real tomograms"
    return intensity_window([packs[0].clean]), f"0.5/99.5 percentiles of the clean volume of {packs[0].path}"


def _slice_plan(source: Source, axis: int, split: str, val_fraction: float) -> dict[str, np.ndarray]:
    """Slice indices of each split (`SPLITS`) of `source` along `axis` for the split mode `split`."""
    n = source.shape[axis]
    if split == "real-test" and source.kind == "synthetic":
        none = np.zeros(0, np.int64)
        return {"train": np.arange(n, dtype=np.int64), "val": none, "test": none}
    return slice_splits(n, val_fraction)


def _min_slices(split_name: str, val_fraction: float) -> int | None:
    """The fewest slices of a volume that give `split_name` a slice under `slice_splits`, or None (up to 10 000)."""
    return next((n for n in range(2, 10_001) if len(slice_splits(n, val_fraction)[split_name])), None)


def _check_plans(plans: list[dict[str, np.ndarray]], sources: list[Source], axis: int, split: str,
                 val_fraction: float) -> None:
    """Raise unless every split gets slices from some source; the message names why one gets none."""
    empty = [s for s in SPLITS if not any(len(plan[s]) for plan in plans)]
    if not empty:
        return
    what = f"no slices for the {' and '.join(empty)} split(s)"
    split_sources = [s for s in sources if split != "real-test" or s.kind == "real"]
    if not split_sources:
        raise SynthpackInputError(f"{what}: with split='real-test' the val and test slices come from real scans; "
                                  "give real scans (--real T L)")
    if "val" in empty and not val_fraction:
        raise SynthpackInputError(f"{what}: val_fraction is 0; use a val_fraction > 0")
    sizes = ", ".join(f"{s.name} has {s.shape[axis]}" for s in split_sources)
    needed = [f"{n} slices for a {name} slice" for name in empty if (n := _min_slices(name, val_fraction))]
    raise SynthpackInputError(
        f"{what}: too few slices along axis {axis} ({sizes})"
        + (f"; with val_fraction {val_fraction:g} a volume needs {' and '.join(needed)}" if needed else "")
        + ": give larger scans, another --axis, or another val_fraction"
    )


# --------------------------------------------------------------------------- #
# Slices
# --------------------------------------------------------------------------- #


@dataclass(frozen=True)
class ExportSlice:
    """One slice whose image `SlicedVolumes.write_images` has written.

    Attributes
    ----------
    split : str
        ``train``, ``val`` or ``test``.
    stem : str
        File name without extension: the image is ``images/<split>/<stem>.png``.
    labels : ndarray of int, shape (H, W)
        The slice's instance labels, 0 = background.
    """

    split: str
    stem: str
    labels: np.ndarray


@dataclass
class SlicedVolumes:
    """The sources of an export, the slices of each split and the intensity window (from `plan_slices`).

    Attributes
    ----------
    sources : list of Source
        Packs first, then real scans, with unique names.
    plans : list of dict
        Per source: split name -> slice indices (int64 arrays) along `axis`.
    axis : int
        Slicing axis.
    window : (float, float)
        Intensity window mapped to 0..255.
    window_from : str
        Where the window came from.
    """

    sources: list[Source]
    plans: list[dict[str, np.ndarray]]
    axis: int
    window: tuple[float, float]
    window_from: str

    def source_records(self) -> list[dict]:
        """Per source: ``name``, ``kind``, ``path``, ``volume``, ``shape``, slices per split and the test block."""
        return [{
            "name": source.name, "kind": source.kind, "path": source.path, "volume": source.volume,
            "shape": list(source.shape), "slices": {s: len(indices) for s, indices in plan.items()},
            "test_block": [int(plan["test"][0]), int(plan["test"][-1]) + 1] if len(plan["test"]) else None,
        } for source, plan in zip(self.sources, self.plans)]

    def write_images(self, root: Path, *, progress: bool = True) -> Iterator[ExportSlice]:
        """Write every slice's 8-bit PNG to ``root/images/<split>/`` and yield it with its labels.

        Parameters
        ----------
        root : Path
            The export's (staging) folder; ``images/{train,val,test}`` are made in it.
        progress : bool
            Show a progress bar.

        Yields
        ------
        ExportSlice
            Every slice of every source, source by source, in slice order.
        """
        for split in SPLITS:
            (root / "images" / split).mkdir(parents=True)
        with progress_bar(total=sum(s.shape[self.axis] for s in self.sources), desc="export", unit="slice",
                  disable=not progress) as bar:
            for source, plan in zip(self.sources, self.plans):
                split_of = {int(i): s for s, indices in plan.items() for i in indices}
                for index in range(source.shape[self.axis]):
                    split, stem = split_of[index], f"{source.name}_a{self.axis}_s{index:04d}"
                    image = to_uint8(read_slice(source.tomogram, self.axis, index), self.window)
                    Image.fromarray(image).save(root / "images" / split / f"{stem}.png")
                    yield ExportSlice(split, stem, np.asarray(read_slice(source.labels, self.axis, index)))
                    bar.update()


def plan_slices(
    packs: Sequence[PathLike],
    real: Sequence[RealScan],
    *,
    axis: int,
    split: str,
    val_fraction: float,
    postprocess: bool,
    window: tuple[float, float] | None,
) -> SlicedVolumes:
    """Open the sources and choose their slices' splits and the intensity window (see the module docstring).

    Parameters are those of `synthpack.export.export_yolo` of the same names, checked
    (`synthpack.export.exporter.SliceSettings.check`). Raises `SynthpackInputError` when a pack or scan cannot be
    read, the window is empty, or a split would get no slices.
    """
    sources, opened = open_sources(packs, real, postprocess=postprocess)
    reals = [source for source in sources if source.kind == "real"]
    chosen, window_from = _choose_window(window, reals, opened)
    plans = [_slice_plan(source, axis, split, val_fraction) for source in sources]
    _check_plans(plans, sources, axis, split, val_fraction)
    return SlicedVolumes(sources, plans, axis, chosen, window_from)


# --------------------------------------------------------------------------- #
# Summary
# --------------------------------------------------------------------------- #


def split_counts() -> dict[str, int]:
    """A zero count per split (for the summaries' per-split count fields)."""
    return dict.fromkeys(SPLITS, 0)


@dataclass
class ExportSummaryBase:
    """What an export wrote: the fields every format shares; each format adds its counts per split.

    Attributes
    ----------
    out : Path
        The dataset folder.
    window : (float, float)
        Intensity window mapped to 0..255.
    window_from : str
        Where the window came from.
    images : dict
        PNG images per split.
    sources : list of dict
        Per source: ``name``, ``kind`` (real / synthetic), ``path``,
        ``volume`` (tomogram / clean), ``shape`` and slices per split.
    settings : dict
        The export's arguments.
    """

    out: Path
    window: tuple[float, float]
    window_from: str
    images: dict[str, int] = field(default_factory=split_counts)
    sources: list[dict] = field(default_factory=list)
    settings: dict = field(default_factory=dict)

    #: ``format`` in the manifest, and the names of the per-split count fields (``images`` first).
    FORMAT: ClassVar[str] = ""
    COUNTS: ClassVar[tuple[str, ...]] = ("images",)

    def add(self, split: str, counts: Mapping[str, int]) -> None:
        """Count one exported image of `split` and add its `counts` (count field name -> number) to that split's."""
        self.images[split] += 1
        for name, number in counts.items():
            getattr(self, name)[split] += number

    def brief(self) -> str:
        """One line of the totals over the splits: ``"120 images, 950 instances, ..."``."""
        return ", ".join(f"{sum(getattr(self, name).values())} {name.replace('_', ' ')}" for name in self.COUNTS)

    def to_dict(self) -> dict:
        """JSON-able form (as in the export's manifest)."""
        counts = {name: getattr(self, name) for name in self.COUNTS}
        return {"format": self.FORMAT, "synthpack": __version__, "out": str(self.out),
                "window": list(self.window), "window_from": self.window_from, **counts,
                "sources": self.sources, "settings": self.settings}

    def table(self) -> str:
        """Markdown table of the counts per split."""
        lines = ["| split | " + " | ".join(name.replace("_", " ") for name in self.COUNTS) + " |",
                 "|---|" + "---|" * len(self.COUNTS)]
        for split in SPLITS:
            lines.append(f"| {split} | " + " | ".join(str(getattr(self, n)[split]) for n in self.COUNTS) + " |")
        return "\n".join(lines)
