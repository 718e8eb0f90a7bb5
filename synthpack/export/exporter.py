"""The one exporter: the steps every dataset export takes, its settings, and the 2D slice loop.

An export is an `ExportWriter` (the format) run by `run_export`, in five steps:

1. check: the settings (`SliceSettings` or `VolumeSettings`), that something is given to
   export, the writer's own options (`ExportWriter.check`) and the output folder
   (`synthpack.io.atomic.check_output`), all before anything is read;
2. plan: `ExportWriter.plan` opens the sources (`synthpack.export.slices`) and plans what
   is written;
3. stage: the folder is built under a temporary name and renamed when complete
   (`synthpack.io.atomic.atomic_directory`, with the writer's `~synthpack.io.atomic.Output`);
4. write: `ExportWriter.write` writes the data and returns the summary, then
   `ExportWriter.dataset_files` adds the files a training framework reads;
5. summary: the summary (``to_dict``) is written to the writer's marker file
   (``OUTPUT.marker``, which marks the folder as this kind of export), logged and returned.

A 2D format subclasses `SliceWriter`: its `SliceWriter.write` is the slice loop (the
intensity window, the splits and the 8-bit PNG images of `synthpack.export.slices`), and
the format adds its labels through hooks: `SliceWriter.start` (its folders),
`SliceWriter.write_slice` (one slice's labels, returning that slice's counts) and
`ExportWriter.dataset_files` (per-split annotation files, ``data.yaml``). So every 2D
format writes the same images under the same names in the same splits. A 3D format (like
`synthpack.export.nnunet`) subclasses `ExportWriter` itself and shares steps 1, 3 and 5.
"""

from __future__ import annotations

import dataclasses
import logging
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from .._shared.schema import one_of, setting
from .._shared.strict_json import dumps as strict_json
from ..errors import SynthpackInputError
from ..io.atomic import Output, atomic_directory, check_output
from ..scan.split import VAL_FRACTION, check_val_fraction
from .slices import (MIN_AREA, SPLIT_MODES, ExportSlice, ExportSummaryBase, PathLike, RealScan, SlicedVolumes,
                     plan_slices)

logger = logging.getLogger(__name__)

__all__ = ["SliceSettings", "VolumeSettings", "ExportWriter", "SliceWriter", "Summary", "check_fields", "run_export"]


def _at_least_one(value: Any) -> bool:
    """>= 1"""
    return value >= 1


def check_fields(settings: Any) -> None:
    """Raise `SynthpackInputError` for the first field of dataclass `settings` whose check refuses its value.

    The checks are those its fields were declared with (`synthpack._shared.schema.setting`);
    ``None`` is never checked. The message reads ``"<field> must be <check's doc>, got <value>"``.
    """
    for field in dataclasses.fields(settings):
        value, check = getattr(settings, field.name), field.metadata.get("check")
        if check is not None and value is not None and not check(value):
            raise SynthpackInputError(f"{field.name} must be {check.__doc__}, got {value!r}")


class _Settings:
    """What the settings dataclasses share: their fields' checks and their record."""

    def check(self) -> None:
        """Raise `SynthpackInputError` for a setting its check refuses (`check_fields`)."""
        check_fields(self)

    def record(self) -> dict:
        """The settings as the export's record (``settings`` in its manifest) holds them, in field order."""
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}  # type: ignore[arg-type]


@dataclass(frozen=True)
class SliceSettings(_Settings):
    """The settings of every 2D slice export (`synthpack.export.export_yolo`, `synthpack.export.export_coco`).

    Attributes
    ----------
    axis : {0, 1, 2}
        Slicing axis of every volume.
    split : {"paper", "real-test"}
        ``"paper"``: every volume gives train, val and test slices; ``"real-test"``:
        synthetic packs give training slices only.
    val_fraction : float
        Fraction of each split volume's slices for validation, next to the test block
        (`synthpack.scan.split.slice_splits`).
    postprocess : bool
        Synthetic images from the post-processed ``tomogram`` (True) or the ``clean`` volume.
    window : (lo, hi), optional
        Intensity window mapped to 0..255; None: chosen from the sources
        (see `synthpack.export.slices`).
    min_area : int
        Pieces of fewer pixels in a slice get no label (what a piece is depends on the format).
    """

    axis: int = setting(0, one_of((0, 1, 2)), "slicing axis")
    split: str = setting(SPLIT_MODES[0], one_of(SPLIT_MODES), "paper: every volume is split; real-test: "
                                                              "synthetic packs give training slices only")
    val_fraction: float = setting(VAL_FRACTION, None, "validation slices per volume, next to the test block")
    postprocess: bool = setting(True, None, "synthetic images from the post-processed tomogram, else the clean volume")
    window: tuple[float, float] | None = setting(None, None, "intensity window (lo, hi) mapped to 0..255")
    min_area: int = setting(MIN_AREA, _at_least_one, "pieces below this many pixels get no label")

    def check(self) -> None:
        """Raise `SynthpackInputError` for a bad setting; the window, when given, must be two finite values lo < hi."""
        super().check()
        check_val_fraction(self.val_fraction)
        if self.window is not None:
            lo, hi = (float(v) for v in self.window)
            if not np.isfinite([lo, hi, hi - lo]).all():
                raise SynthpackInputError(f"the window must be finite, got ({lo:g}, {hi:g}): give two grey values "
                                          "of the tomograms, lo < hi")
            if not hi > lo:
                raise SynthpackInputError(f"the window needs lo < hi, got ({lo:g}, {hi:g})")

    def record(self) -> dict:
        """The settings but the window, which the summary holds on its own (with where it came from)."""
        return {name: value for name, value in super().record().items() if name != "window"}


@dataclass(frozen=True)
class VolumeSettings(_Settings):
    """The settings of a 3D volume export (`synthpack.export.export_nnunet`).

    Attributes
    ----------
    axis : {0, 1, 2}
        The axis along which each split volume's central 20% test block is taken.
    split : {"real-test", "paper"}
        ``"real-test"``: a pack is one whole training case; ``"paper"``: a pack is split
        like a real scan (training slabs and a test block).
    postprocess : bool
        Pack images from the post-processed tomogram (True) or the clean volume.
    """

    axis: int = setting(0, one_of((0, 1, 2)), "axis of the central 20% test block")
    split: str = setting("real-test", one_of(SPLIT_MODES), "real-test: packs are whole training cases; "
                                                             "paper: packs are split like real scans")
    postprocess: bool = setting(True, None, "pack images from the post-processed tomogram, else the clean volume")


class Summary(Protocol):
    """What an export returns and records: its manifest, a table for people and a line for the log."""

    def to_dict(self) -> dict: ...

    def table(self) -> str: ...

    def brief(self) -> str: ...


class ExportWriter(ABC):
    """One export format: its output folder, its settings, and what it writes (see the module docstring).

    A writer is a dataclass whose init fields are the format's own options, declared with
    `synthpack._shared.schema.setting` (YOLO's ``tolerance``); other fields may keep what it
    has written so far (the COCO annotations of each split), so a writer writes one export:
    make a new one for each.

    Attributes
    ----------
    OUTPUT : Output
        The kind of folder it writes; ``OUTPUT.marker`` is the summary's file.
    SETTINGS : type
        `SliceSettings` or `VolumeSettings`: the settings the format takes beside its own options.
    """

    OUTPUT: ClassVar[Output]
    SETTINGS: ClassVar[type[SliceSettings | VolumeSettings]]

    def check(self, out: Path) -> None:
        """Raise `SynthpackInputError` for a bad option of the format (or folder name `out`), before anything is read.

        By default the checks of the writer's fields (`check_fields`).
        """
        check_fields(self)

    @abstractmethod
    def plan(self, packs: Sequence[PathLike], real: Sequence[RealScan], settings: Any) -> Any:
        """Open the sources and plan what is written (anything `write` takes); raise for unusable inputs."""

    @abstractmethod
    def write(self, staging: Path, out: Path, plan: Any, settings: Any, progress: bool) -> Summary:
        """Write the data of `plan` into the `staging` folder (renamed to `out` when complete); return the summary."""

    def dataset_files(self, out: Path, summary: Any) -> Iterator[tuple[str, str]]:
        """``(relative path, text)`` of each file written after the data, beside the summary's; default none."""
        return iter(())


def run_export(
    writer: ExportWriter,
    out: PathLike,
    packs: Sequence[PathLike],
    real: Sequence[RealScan],
    settings: SliceSettings | VolumeSettings,
    *,
    progress: bool,
    overwrite: bool,
) -> Any:
    """Check, plan, stage, write and record one export (the steps of the module docstring).

    Parameters
    ----------
    writer : ExportWriter
        The format, with its own options.
    out : path-like
        Output folder; must be new, empty or an earlier export of the same kind
        (replaced), or any folder with `overwrite`.
    packs, real
        Pack folders (or folders holding them) and labelled real scans (`Scan` objects or
        ``(tomogram, labels)`` path pairs), as in `synthpack.export.export_yolo`.
    settings : SliceSettings or VolumeSettings
        As `writer.SETTINGS`.
    progress : bool
        Show a progress bar.
    overwrite : bool
        Write into a folder that holds something other than an earlier export of this kind.

    Returns
    -------
    The writer's summary.

    Raises
    ------
    SynthpackInputError
        Before anything is written: a bad setting or option, nothing to export, an output
        that may not be written, or sources that cannot be read or planned.
    """
    out = Path(out)
    settings.check()
    if not (packs or real):
        raise SynthpackInputError("nothing to export: give pack folders (--packs) and/or real scans (--real T L)")
    writer.check(out)
    check_output(out, writer.OUTPUT, overwrite=overwrite)
    plan = writer.plan(packs, real, settings)
    with atomic_directory(out, writer.OUTPUT, overwrite=overwrite) as staging:
        summary = writer.write(staging, out, plan, settings, progress)
        for name, text in writer.dataset_files(out, summary):
            (staging / name).parent.mkdir(parents=True, exist_ok=True)
            (staging / name).write_text(text)
        (staging / writer.OUTPUT.marker).write_text(strict_json(summary.to_dict(), indent=1))
    logger.info("%s in %s: %s", writer.OUTPUT.what, out, summary.brief())
    return summary


class SliceWriter(ExportWriter):
    """A 2D slice format: the slice loop of `synthpack.export.slices`, with the format's label hooks.

    Attributes
    ----------
    SUMMARY : type
        Its summary, a subclass of `synthpack.export.slices.ExportSummaryBase` whose
        count fields `write_slice`'s counts name.
    """

    SETTINGS = SliceSettings
    SUMMARY: ClassVar[type[ExportSummaryBase]]

    def plan(self, packs: Sequence[PathLike], real: Sequence[RealScan], settings: SliceSettings) -> SlicedVolumes:
        """The sources, their slices' splits and the intensity window (`synthpack.export.slices.plan_slices`)."""
        return plan_slices(packs, real, axis=settings.axis, split=settings.split, val_fraction=settings.val_fraction,
                           postprocess=settings.postprocess, window=settings.window)

    def write(self, staging: Path, out: Path, plan: SlicedVolumes, settings: SliceSettings,
              progress: bool) -> ExportSummaryBase:
        """Write every slice's image and, through `write_slice`, its labels; count them in the summary.

        The summary's ``settings`` are the slicing settings' record, then `record`'s.
        """
        summary = self.SUMMARY(out, plan.window, plan.window_from, settings={**settings.record(), **self.record()})
        self.start(staging)
        for item in plan.write_images(staging, progress=progress):
            summary.add(item.split, self.write_slice(staging, item, settings))
        summary.sources = plan.source_records()
        return summary

    def record(self) -> dict:
        """The format's own options (and constants) for the summary's ``settings``; default none."""
        return {}

    def start(self, staging: Path) -> None:
        """Make the format's folders in `staging` before the first slice; default none."""

    @abstractmethod
    def write_slice(self, staging: Path, item: ExportSlice, settings: SliceSettings) -> Mapping[str, int]:
        """Write the labels of one slice (its image is written); return its counts by summary field name.

        The counts are added to the summary's fields of `item.split` (the image itself is counted
        in ``images``).
        """
