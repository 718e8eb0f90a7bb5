"""A toy export format, registered only by tests/test_export_registry.py to prove the extension point.

Beside the PNG slices of the shared slice loop, a toy export holds, per slice,
``sizes/<split>/<stem>.txt``: one line ``label pixels`` per instance of at least
`min_area` pixels, ordered by its option `order`; and ``splits.txt``: the images per
split. Its writer and summary are all a new 2D format needs beside its
`~synthpack.export.registry.ExportFormat` line.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from synthpack._shared.schema import one_of, setting
from synthpack.export.exporter import SliceSettings, SliceWriter
from synthpack.export.slices import ExportSlice, ExportSummaryBase, split_counts
from synthpack.io.atomic import Output
from synthpack.scan.split import SPLITS

#: A toy dataset folder, marked by its summary file.
TOY_OUTPUT = Output("toy dataset", marker="toy_export.json")


@dataclass
class ToySummary(ExportSummaryBase):
    """What a toy export wrote: the shared fields and the instances listed per split."""

    instances: dict[str, int] = field(default_factory=split_counts)

    FORMAT: ClassVar[str] = "toy-sizes"
    COUNTS: ClassVar[tuple[str, ...]] = ("images", "instances")


@dataclass
class ToyWriter(SliceWriter):
    """The toy format's hooks: one sizes file per slice, and ``splits.txt``."""

    order: str = setting("label", one_of(("label", "size")), "line order: by label, or by size (largest first)")

    OUTPUT: ClassVar[Output] = TOY_OUTPUT
    SUMMARY: ClassVar[type[ExportSummaryBase]] = ToySummary

    def record(self) -> dict:
        return {"order": self.order}

    def start(self, staging: Path) -> None:
        for split in SPLITS:
            (staging / "sizes" / split).mkdir(parents=True)

    def write_slice(self, staging: Path, item: ExportSlice, settings: SliceSettings) -> dict[str, int]:
        values, sizes = np.unique(item.labels[item.labels > 0], return_counts=True)
        rows = [(int(v), int(n)) for v, n in zip(values, sizes) if n >= settings.min_area]
        if self.order == "size":
            rows.sort(key=lambda row: (-row[1], row[0]))
        (staging / "sizes" / item.split / f"{item.stem}.txt").write_text("".join(f"{v} {n}\n" for v, n in rows))
        return {"instances": len(rows)}

    def dataset_files(self, out: Path, summary: ToySummary) -> Iterator[tuple[str, str]]:
        yield "splits.txt", "".join(f"{split} {summary.images[split]}\n" for split in SPLITS)
