"""Export packs and labelled real scans as an nnU-Net v2 raw dataset (3D volumes, NIfTI).

Layout of the output folder ``OUT``, which must be named ``DatasetNNN_Name``
(nnU-Net's dataset id, three digits 001-999, and name) and is meant to sit in
``$nnUNet_raw``::

    dataset.json                       what nnU-Net reads: channels, labels, numTraining, file_ending
    nnunet_export.json                 synthpack's record: settings, sources, every case (marks OUT as an export)
    imagesTr/Name_NNN_0000.nii.gz      training images (channel 0000, the only one)
    labelsTr/Name_NNN.nii.gz           their semantic targets
    imagesTs/Name_NNN_0000.nii.gz      test images (nnU-Net does not use them: ``nnUNetv2_predict -i``)
    labelsTs/Name_NNN.nii.gz           their targets, for evaluation (nnU-Net ignores the folder)

Then ``nnUNetv2_plan_and_preprocess -d NNN --verify_dataset_integrity`` and
``nnUNetv2_train NNN 3d_fullres 0`` train on it.

Format decisions
----------------
File format
    NIfTI ``.nii.gz`` (`synthpack.io.write_nifti`): nnU-Net's reference format,
    read by its default reader (SimpleITKIO) and by NibabelIO alike, one
    self-describing file per case with its voxel size in the header, which
    ITK-SNAP, 3D Slicer and synthpack itself open. (nnU-Net's 3D TIFF reader
    would need a JSON spacing sidecar per file, which no other tool reads.)
    The array is stored (x, y, z) as NIfTI wants, so every reader's (Z, Y, X)
    array is the source volume's, and nnU-Net's spacing is synthpack's
    ``(dz, dy, dx)``.
Cases
    Along `axis`, each volume's slices are split by the paper's rule
    (`synthpack.scan.split.central_block`: the central 20% are the test block).
    A real scan gives its test block as a test case (``imagesTs``) and each
    of the two slabs on either side of it as a training case of its own (the
    slabs are not adjacent, so they are not joined). A synthetic pack gives
    its whole volume as one training case with ``split="real-test"`` (the
    default here: train on real + synthetic, test on real), or, with
    ``split="paper"``, its two slabs for training and its central block as a
    test case, like a real scan. There is no validation split: nnU-Net makes
    its own (5-fold cross-validation over the training cases).
    Cases are numbered ``Name_000``, ``Name_001``, ... (wider past 999),
    training cases first, in source order (packs, then real scans); each
    case's source, part and block (``[start, stop)`` along `axis`) are in
    ``nnunet_export.json``. A case's affine places it where its block lies
    in its volume.
Semantic target (labels)
    ``0`` background, ``1`` grain (interior), ``2`` boundary: the grain
    voxels one of whose six face neighbours holds another label (another
    grain or the background); see `semantic_target`. So two touching grains
    are parted by two boundary layers (one of each), and no face neighbour of
    an interior voxel belongs to another grain: the 6-connected components of
    class 1 never join two grains. A case's target is the whole volume's,
    cropped (a slab's cut face is no boundary), and the volume's outer faces
    are no boundary either (a grain cut by the scan's edge goes on beyond it).
Recovering instances
    `instances_from_target`: the 6-connected components of class 1 are the
    seeds, grown over the class-2 voxels by flooding within ``target > 0``
    (every boundary voxel joins the seed nearest it through grain voxels,
    `skimage.segmentation.watershed` on a flat image); grain voxels no seed
    reaches (a grain at most two voxels thick is all boundary) become
    instances of their own (their 6-connected components). For a grain that
    touches no other one and has a 6-connected interior this gives the grain
    exactly; where grains touch, a boundary voxel equally near two seeds
    (at an edge or corner of the contact) may go to either.
    The same applies to an nnU-Net prediction.
Intensities
    The images are the tomograms' values in their own dtype (a pack's
    post-processed tomogram, or its clean volume without `postprocess`),
    with no intensity window: the channel is named ``CT``, so nnU-Net
    normalises every case with one clip and z-score measured on the
    training cases' foreground, which needs the packs and the real scans in
    the same intensity scale (a pack calibrated to its source scan is).
Voxel size
    A pack's voxel size, and a real scan's from its file metadata (or its
    `~synthpack.scan.core.Scan`). nnU-Net resamples every case to one target
    spacing, so all sources must be in one length unit: each is converted to
    the first source's unit (nm, um, mm, cm, m), and sources whose units do
    not convert (voxels, ``px``, beside a length) are refused.

Memory: one case is in memory at a time (image, labels and target). The
output folder is built under a temporary name and renamed when complete; an
existing folder is only replaced if it is an earlier nnU-Net export.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
from scipy import ndimage

from .. import __version__
from .._shared.console import progress_bar
from .._shared.schema import default_of
from .._shared.strict_json import dumps as strict_json
from ..errors import SynthpackInputError
from ..io import check_nifti_writer, convert_voxel_size, read_box, write_nifti
from ..io.atomic import Output
from ..scan.split import central_block
from .exporter import ExportWriter, VolumeSettings, run_export
from .slices import PathLike, RealScan, Source, open_sources

__all__ = ["DEFAULT_SPLIT", "LABELS", "NNUNET_OUTPUT", "NnUNetExportSummary", "NnUNetWriter", "export_nnunet",
           "instances_from_target", "semantic_target"]

#: The export's default split mode: packs train whole, real scans give their central 20% as test cases.
DEFAULT_SPLIT = default_of(VolumeSettings, "split")
#: The target's classes, as ``dataset.json`` names them.
LABELS = {"background": 0, "grain": 1, "boundary": 2}
#: The file ending of every image and target.
FILE_ENDING = ".nii.gz"
#: An nnU-Net raw dataset folder: an earlier export (``nnunet_export.json``) is replaced, anything else is refused.
NNUNET_OUTPUT = Output("nnU-Net dataset", marker="nnunet_export.json")

_FOLDER = re.compile(r"^Dataset(?P<id>\d{3})_(?P<name>[A-Za-z0-9][A-Za-z0-9_-]*)$")
# 6-connectivity (faces only), for the components of `instances_from_target`
_FACES = ndimage.generate_binary_structure(3, 1)


def semantic_target(labels: np.ndarray) -> np.ndarray:
    """The nnU-Net target of an instance label volume: background 0, grain interior 1, boundary 2.

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X)
        Instance labels, 0 = background.

    Returns
    -------
    ndarray of uint8, shape (Z, Y, X)
        ``0`` where ``labels == 0``; ``2`` at a grain voxel (``labels > 0``)
        with at least one face neighbour (the six voxels at distance 1 along
        z, y or x) inside the array whose label differs (another grain or the
        background); ``1`` at the other grain voxels. Neighbours beyond the
        array's faces do not count, so ``target > 0`` equals ``labels > 0``.

    Examples
    --------
    >>> labels = np.zeros((1, 1, 7), int); labels[0, 0, 1:4] = 1; labels[0, 0, 4:6] = 2
    >>> semantic_target(labels)[0, 0].tolist()
    [0, 2, 1, 2, 2, 2, 0]
    """
    labels = np.asarray(labels)
    if labels.ndim != 3:
        raise SynthpackInputError(f"a label volume must be 3D, got shape {labels.shape}")
    boundary = np.zeros(labels.shape, bool)
    for axis in range(3):
        low = (slice(None),) * axis + (slice(None, -1),)
        high = (slice(None),) * axis + (slice(1, None),)
        differs = labels[low] != labels[high]
        boundary[low] |= differs
        boundary[high] |= differs
    grain = labels > 0
    return grain.astype(np.uint8) + (boundary & grain).astype(np.uint8)


def instances_from_target(target: np.ndarray) -> np.ndarray:
    """Instance labels recovered from a semantic target (or an nnU-Net prediction of one).

    Parameters
    ----------
    target : ndarray of int, shape (Z, Y, X)
        0 background, 1 grain interior, 2 boundary (`semantic_target`).

    Returns
    -------
    ndarray of int32, shape (Z, Y, X)
        0 where ``target == 0``; elsewhere one label per instance, numbered
        from 1: the 6-connected components of class 1, each grown over the
        class-2 voxels nearest it through ``target > 0`` (watershed flooding
        of a flat image), then the 6-connected components of the grain
        voxels no component reaches. See "Recovering instances" in
        `synthpack.export.nnunet` for when this gives the grains exactly.
    """
    from skimage.segmentation import watershed

    target = np.asarray(target)
    if target.ndim != 3:
        raise SynthpackInputError(f"a target volume must be 3D, got shape {target.shape}")
    grain = target > 0
    seeds, n_seeds = ndimage.label(target == 1, structure=_FACES)
    grown = watershed(np.zeros(target.shape, np.uint8), seeds, connectivity=1, mask=grain).astype(np.int32)
    rest, _ = ndimage.label(grain & (grown == 0), structure=_FACES)
    grown[rest > 0] = rest[rest > 0] + n_seeds
    return grown


@dataclass
class NnUNetExportSummary:
    """What `export_nnunet` wrote.

    Attributes
    ----------
    out : Path
        The dataset folder ``DatasetNNN_Name``.
    dataset_id : int
        nnU-Net's dataset id.
    name : str
        The dataset name, also the case names' prefix.
    unit : str
        Length unit of every case's voxel size.
    cases : list of dict
        Per case: ``case`` (its identifier), ``set`` (``"Tr"`` or ``"Ts"``),
        ``source``, ``part`` (``"all"``, ``"train"`` or ``"test"``), ``block``
        (``[start, stop)`` along the split axis), ``shape``, ``voxel_size``
        (dz, dy, dx), ``grains`` (instances in the case) and ``voxels`` per class.
    sources : list of dict
        Per source: ``name``, ``kind``, ``path``, ``volume``, ``shape``,
        ``voxel_size`` (in `unit`) and ``test_block`` (or None).
    settings : dict
        The export's arguments.
    """

    out: Path
    dataset_id: int
    name: str
    unit: str
    cases: list[dict] = field(default_factory=list)
    sources: list[dict] = field(default_factory=list)
    settings: dict = field(default_factory=dict)

    FORMAT = "synthpack-nnunet-v2"

    def count(self, which: str) -> int:
        """Cases of the set `which` (``"Tr"`` or ``"Ts"``)."""
        return sum(case["set"] == which for case in self.cases)

    def to_dict(self) -> dict:
        """JSON-able form (``nnunet_export.json``)."""
        return {"format": self.FORMAT, "synthpack": __version__, "out": str(self.out), "dataset_id": self.dataset_id,
                "name": self.name, "unit": self.unit, "labels": LABELS, "sources": self.sources,
                "cases": self.cases, "settings": self.settings}

    def brief(self) -> str:
        """One line: ``"3 training and 1 test cases"``."""
        return f"{self.count('Tr')} training and {self.count('Ts')} test cases"

    def table(self) -> str:
        """Markdown table of the cases: one row each."""
        lines = ["| case | set | source | part | block | shape | grains |", "|---|---|---|---|---|---|---|"]
        for case in self.cases:
            lines.append(f"| {case['case']} | {case['set']} | {case['source']} | {case['part']} | "
                         f"{case['block'][0]}-{case['block'][1]} | {'x'.join(map(str, case['shape']))} | "
                         f"{case['grains']} |")
        return "\n".join(lines)


def _dataset_folder(out: Path) -> tuple[int, str]:
    """nnU-Net's dataset id and name from the folder name ``DatasetNNN_Name``."""
    match = _FOLDER.match(out.name)
    if match is None or int(match["id"]) == 0:
        raise SynthpackInputError(
            f"the nnU-Net dataset folder must be named DatasetNNN_Name (a three-digit id 001-999 and a name of "
            f"letters, digits, _ and -), got {out.name!r}: e.g. --out $nnUNet_raw/Dataset501_Grains")
    return int(match["id"]), match["name"]


def _common_unit(sources: list[Source]) -> None:
    """Convert every source's voxel size to the first one's unit (in place); refuse units that do not convert."""
    unit = sources[0].unit
    for source in sources:
        if source.unit == unit:
            continue
        converted = convert_voxel_size(source.voxel_size, source.unit, unit)
        if converted is None:
            raise SynthpackInputError(
                f"{source.name} has its voxel size in {source.unit!r} but {sources[0].name} in {unit!r}, which do "
                "not convert: nnU-Net needs one unit; give real scans whose files record their voxel size (or a "
                "Scan with voxel_size and unit) in a unit the packs' converts to")
        source.voxel_size, source.unit = converted, unit


def _parts(source: Source, axis: int, split: str) -> list[tuple[str, int, int]]:
    """``(part, start, stop)`` blocks of `source` along `axis`: the training slabs first, then the test block."""
    n = source.shape[axis]
    if split == "real-test" and source.kind == "synthetic":
        return [("all", 0, n)]
    start, stop = central_block(n)
    slabs = [("train", lo, hi) for lo, hi in ((0, start), (stop, n)) if hi > lo]
    return slabs + [("test", start, stop)]


def _read_part(volume, axis: int, start: int, stop: int, shape: tuple[int, int, int]) -> np.ndarray:
    """The block ``[start, stop)`` along `axis` of `volume` (read alone)."""
    origin, size = [0, 0, 0], list(shape)
    origin[axis], size[axis] = start, stop - start
    return read_box(volume, origin, size)


def _case_target(source: Source, axis: int, start: int, stop: int) -> np.ndarray:
    """`semantic_target` of the source's whole label volume, cropped to ``[start, stop)`` along `axis`.

    Only the block and one neighbouring slice on each side (where the volume has one) are read.
    """
    low, high = max(start - 1, 0), min(stop + 1, source.shape[axis])
    target = semantic_target(_read_part(source.labels, axis, low, high, source.shape))
    return target[(slice(None),) * axis + (slice(start - low, stop - low),)]


@dataclass
class NnUNetWriter(ExportWriter):
    """The nnU-Net format on the exporter's steps (`synthpack.export.exporter`): 3D cases, ``dataset.json``.

    It takes the sources from `synthpack.export.slices.open_sources` (with their voxel
    sizes, converted to one unit), splits each one into cases (`_parts`) and writes one
    case at a time.
    """

    OUTPUT: ClassVar[Output] = NNUNET_OUTPUT
    SETTINGS = VolumeSettings

    def check(self, out: Path) -> None:
        """Refuse a folder not named ``DatasetNNN_Name``, or a missing NIfTI writer."""
        _dataset_folder(out)
        check_nifti_writer()

    def plan(self, packs: Sequence[PathLike], real: Sequence[RealScan], settings: VolumeSettings) -> list[Source]:
        """The sources, their voxel sizes in the first one's unit."""
        sources, _ = open_sources(packs, real, postprocess=settings.postprocess, voxel_size=True)
        _common_unit(sources)
        return sources

    def write(self, staging: Path, out: Path, plan: list[Source], settings: VolumeSettings,
              progress: bool) -> NnUNetExportSummary:
        """Write every case of every source, training cases first; return the summary."""
        dataset_id, name = _dataset_folder(out)
        summary = NnUNetExportSummary(out, dataset_id, name, plan[0].unit, settings={
            **settings.record(), "labels": LABELS, "file_ending": FILE_ENDING})
        axis = settings.axis
        planned = [(source, part) for source in plan for part in _parts(source, axis, settings.split)]
        planned.sort(key=lambda item: item[1][0] == "test")  # training cases first, in source order
        width = max(3, len(str(len(planned) - 1)))
        for number, (source, (part, start, stop)) in enumerate(progress_bar(planned, desc="export", unit="case",
                                                                            disable=not progress)):
            summary.cases.append(_write_case(staging, f"{name}_{number:0{width}d}", source, axis, part, start, stop))
        summary.sources = [{
            "name": source.name, "kind": source.kind, "path": source.path, "volume": source.volume,
            "shape": list(source.shape), "voxel_size": list(source.voxel_size),
            "test_block": next(([start, stop] for part, start, stop in _parts(source, axis, settings.split)
                                if part == "test"), None),
        } for source in plan]
        return summary

    def dataset_files(self, out: Path, summary: NnUNetExportSummary) -> Iterator[tuple[str, str]]:
        """nnU-Net v2's ``dataset.json``: its four required keys, plus a name and description it ignores."""
        yield "dataset.json", strict_json({
            "channel_names": {"0": "CT"},
            "labels": LABELS,
            "numTraining": summary.count("Tr"),
            "file_ending": FILE_ENDING,
            "name": summary.name,
            "description": f"synthpack {__version__} export: synthetic particle packs and labelled real scans; "
                           "target 0 background, 1 grain interior, 2 grain boundary (see nnunet_export.json)",
            "numTest": summary.count("Ts"),
        }, indent=1)


def export_nnunet(
    out: PathLike,
    packs: Sequence[PathLike] = (),
    real: Sequence[RealScan] = (),
    *,
    axis: int = default_of(VolumeSettings, "axis"),
    split: str = DEFAULT_SPLIT,
    postprocess: bool = default_of(VolumeSettings, "postprocess"),
    progress: bool = True,
    overwrite: bool = False,
) -> NnUNetExportSummary:
    """Write packs and real scans as an nnU-Net v2 raw dataset (layout and format: module docstring).

    Parameters
    ----------
    out : path-like
        The dataset folder, named ``DatasetNNN_Name`` (e.g.
        ``$nnUNet_raw/Dataset501_Grains``); must be new, empty or an earlier
        nnU-Net export (replaced), or any folder with `overwrite` (the
        export's files are written into it and its other files are kept).
    packs : sequence of path-like
        Pack folders, or folders holding ``pack_NNNN`` folders.
    real : sequence of Scan or (path, path)
        Labelled real scans: `~synthpack.scan.core.Scan` objects, or
        ``(tomogram, labels)`` paths read with their voxel size.
    axis : {0, 1, 2}
        The axis along which the central 20% test block is taken.
    split : {"real-test", "paper"}
        ``"real-test"``: a pack is one whole training case; ``"paper"``: a
        pack is split like a real scan (two training slabs, one test block).
    postprocess : bool
        Pack images from the post-processed tomogram (default) or the clean volume.
    progress : bool
        Show a progress bar.
    overwrite : bool
        Write into a folder that holds something other than an earlier nnU-Net export.

    Returns
    -------
    NnUNetExportSummary

    Raises
    ------
    SynthpackInputError
        Before anything is written: a bad folder name or setting, no inputs,
        an unreadable pack or scan, or voxel sizes in units that do not convert.
    """
    return run_export(NnUNetWriter(), out, packs, real, VolumeSettings(axis=axis, split=split, postprocess=postprocess),
                      progress=progress, overwrite=overwrite)


def _write_case(root: Path, case: str, source: Source, axis: int, part: str, start: int, stop: int) -> dict:
    """Write one case's image and target under `root` and return its record (see `NnUNetExportSummary.cases`)."""
    which = "Ts" if part == "test" else "Tr"
    image = _read_part(source.tomogram, axis, start, stop, source.shape)
    labels = _read_part(source.labels, axis, start, stop, source.shape)
    target = _case_target(source, axis, start, stop)
    origin = [0.0, 0.0, 0.0]
    origin[axis] = start * source.voxel_size[axis]
    for folder, stem, volume in ((f"images{which}", f"{case}_0000", image), (f"labels{which}", case, target)):
        (root / folder).mkdir(exist_ok=True)
        write_nifti(root / folder / f"{stem}{FILE_ENDING}", volume, source.voxel_size, source.unit,
                    origin=tuple(origin))
    counts = np.bincount(target.ravel(), minlength=len(LABELS))
    return {"case": case, "set": which, "source": source.name, "part": part, "block": [start, stop],
            "shape": list(image.shape), "voxel_size": list(source.voxel_size),
            "grains": int(np.count_nonzero(np.unique(labels))),
            "voxels": {label: int(counts[value]) for label, value in LABELS.items()}}

