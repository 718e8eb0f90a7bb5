"""What the synthetic packs are made from: a built-in sample, a labelled scan on disk, or a library."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import SynthpackInputError
from ..io import read_scan
from ..scan.samples import SAMPLE_NAMES, sample_scan
from ..scan.core import Scan

__all__ = ["SAMPLE_SEED", "PackSource"]

#: Seed of the built-in sample scans used as a source.
SAMPLE_SEED = 0


@dataclass(frozen=True)
class PackSource:
    """Where the grains come from: a built-in sample, a labelled scan on disk, or a particle library.

    Attributes
    ----------
    kind : {"sample", "scan", "library"}
    name : str
        The sample's name (``kind == "sample"``).
    paths : tuple of Path
        ``(tomogram, labels)`` of a scan, or ``(library directory,)``; resolved.
    """

    kind: str
    name: str = ""
    paths: tuple[Path, ...] = ()

    @classmethod
    def parse(cls, source: Any) -> PackSource:
        """A sample name, a ``(tomogram_path, labels_path)`` pair, or a library directory (see the dataset)."""
        if isinstance(source, str) and source in SAMPLE_NAMES:
            return cls("sample", name=source)
        if isinstance(source, (tuple, list)) and len(source) == 2:
            paths = tuple(Path(p).expanduser().resolve() for p in source)
            missing = [str(p) for p in paths if not p.exists()]
            if missing:
                raise SynthpackInputError(f"source scan file(s) {', '.join(missing)} do not exist")
            return cls("scan", paths=paths)
        if isinstance(source, (str, os.PathLike)):
            path = Path(source).expanduser().resolve()
            if (path / "library.json").is_file():
                return cls("library", paths=(path,))
            raise SynthpackInputError(
                f"source {str(source)!r} is neither a sample name ({', '.join(SAMPLE_NAMES)}) nor a "
                "particle library directory (with library.json): give one of those, or a "
                "(tomogram_path, labels_path) pair"
            )
        raise SynthpackInputError(
            f"source {source!r} is not understood: give a sample name ({', '.join(SAMPLE_NAMES)}), "
            "a (tomogram_path, labels_path) pair or a particle library directory"
        )

    def identity(self) -> dict:
        """What the cache key depends on: sample name and seed, file sizes and times, or library content."""
        if self.kind == "sample":
            return {"sample": self.name, "seed": SAMPLE_SEED}
        if self.kind == "scan":
            return {"scan": [_file_identity(path) for path in self.paths]}
        return {"library_json_sha256": hashlib.sha256((self.paths[0] / "library.json").read_bytes()).hexdigest()}

    def read_scan(self) -> Scan:
        """The labelled scan of a sample or scan source, read now (a library source has none)."""
        if self.kind == "sample":
            return sample_scan(self.name, seed=SAMPLE_SEED)
        if self.kind == "scan":
            return read_scan(*self.paths)
        raise SynthpackInputError(f"the source {self.describe()} is a particle library, not a scan")

    def describe(self) -> str:
        """One line for logs, manifests and ``repr``."""
        if self.kind == "sample":
            return f"sample:{self.name}"
        if self.kind == "scan":
            return f"tomogram={self.paths[0]}; labels={self.paths[1]}"
        return f"library:{self.paths[0]}"


def _file_identity(path: Path) -> list:
    """``[path, [[relative file, size, mtime_ns], ...]]`` of a file or of every file of a folder."""
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return [str(path), [[str(f.relative_to(path)) if path.is_dir() else f.name, f.stat().st_size,
                         f.stat().st_mtime_ns] for f in files]]
