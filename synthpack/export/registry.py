"""The export formats, one `ExportFormat` record each: the one list that `export` writes by name.

A new export format is one module of this package holding its writer (a
`~synthpack.export.exporter.SliceWriter` for a 2D format, which adds its labels to the
shared slice loop, or an `~synthpack.export.exporter.ExportWriter` for a 3D one) and one
`ExportFormat` line in `FORMATS`; `export` then writes it by name, with its settings and
its writer's options as keywords.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..errors import SynthpackInputError
from ..io.atomic import Output
from .coco import CocoWriter
from .exporter import ExportWriter, Summary, run_export
from .nnunet import NnUNetWriter
from .slices import PathLike, RealScan
from .yolo import YoloWriter

__all__ = ["ExportFormat", "FORMATS", "export", "get_format"]


@dataclass(frozen=True)
class ExportFormat:
    """One export format: its name, its writer and the command that writes it.

    Attributes
    ----------
    name : str
        What `export` and messages call it: ``"yolo"``.
    writer : type
        Its `~synthpack.export.exporter.ExportWriter` class; its ``SETTINGS`` are the
        settings it takes (2D slices or 3D volumes) and its init fields its own options.
    command : str, optional
        The ``synthpack`` subcommand that writes it (``"export-yolo"``), if it has one.
    """

    name: str
    writer: type[ExportWriter]
    command: str | None = None

    @property
    def output(self) -> Output:
        """The kind of output folder it writes (its marker file holds the export's summary)."""
        return self.writer.OUTPUT

    def options(self) -> tuple[str, ...]:
        """The keywords `export` takes for it: its settings' names, then its writer's own options."""
        fields = (*dataclasses.fields(self.writer.SETTINGS), *dataclasses.fields(self.writer))
        return tuple(field.name for field in fields if field.init)


#: The export formats, in the order they are listed.
FORMATS: tuple[ExportFormat, ...] = (
    ExportFormat("yolo", YoloWriter, command="export-yolo"),
    ExportFormat("coco", CocoWriter, command="export-coco"),
    ExportFormat("nnunet", NnUNetWriter, command="export-nnunet"),
)


def get_format(name: str) -> ExportFormat:
    """The export format called `name`.

    Raises
    ------
    SynthpackInputError
        For a name that is not in `FORMATS`.
    """
    for fmt in FORMATS:
        if fmt.name == name:
            return fmt
    raise SynthpackInputError(f"unknown export format {name!r}; choose one of: {', '.join(f.name for f in FORMATS)}")


def export(
    name: str,
    out: PathLike,
    packs: Sequence[PathLike] = (),
    real: Sequence[RealScan] = (),
    *,
    progress: bool = True,
    overwrite: bool = False,
    **options: Any,
) -> Summary:
    """Write packs and real scans as a dataset of the export format called `name`.

    ``export("yolo", out, packs, real, axis=1, tolerance=0.5)`` writes what
    ``export_yolo(out, packs, real, axis=1, tolerance=0.5)`` writes.

    Parameters
    ----------
    name : str
        The format (`FORMATS`): ``"yolo"``, ``"coco"``, ``"nnunet"``.
    out, packs, real, progress, overwrite
        As in `synthpack.export.exporter.run_export`.
    **options
        The format's settings (`~synthpack.export.exporter.SliceSettings` or
        `~synthpack.export.exporter.VolumeSettings`) and its writer's own options
        (`ExportFormat.options`); those not given take their defaults.

    Returns
    -------
    The format's summary.

    Raises
    ------
    SynthpackInputError
        For an unknown format or option, and as `run_export`.
    """
    fmt = get_format(name)
    unknown = sorted(set(options) - set(fmt.options()))
    if unknown:
        raise SynthpackInputError(f"unknown option(s) {', '.join(unknown)} of the {name} export; its options: "
                                  f"{', '.join(fmt.options())}")
    settings_names = {field.name for field in dataclasses.fields(fmt.writer.SETTINGS)}
    settings = fmt.writer.SETTINGS(**{k: v for k, v in options.items() if k in settings_names})
    writer = fmt.writer(**{k: v for k, v in options.items() if k not in settings_names})
    return run_export(writer, out, packs, real, settings, progress=progress, overwrite=overwrite)
