"""The pack cache: packs of one source and config, kept under a content-hash key and built when missing.

This is the synthetic dataset's materialisation step (torchvision's
``_check_exists()`` and ``download()``), kept apart from loading: `PackCache.check`
finds the usable cached packs, `PackCache.build` runs the pipeline (particle
library, then `synthpack.pipeline.generate.generate_packs`) for the others.

Layout under the cache root::

    packs-<key>/pack_0000, ...      the packs; <key> hashes source, config, format, version
    packs-<key>/key.json            what <key> covers
    packs-<key>/verified.json       size and modification time of each pack file when its
                                    checksums were last verified
    library-<key>/library           the particle library built from a scan source
    library-<key>/key.json          (<key> hashes source, library config, version)
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
from collections.abc import Sequence
from pathlib import Path

from .. import __version__
from .._shared.strict_json import dumps as strict_json
from ..io.atomic import atomic_file
from ..pipeline.config import PackConfig
from ..errors import SynthpackInputError
from ..pipeline.generate import generate_packs, pack_name
from ..library.core import ParticleLibrary
from ..store.pack import is_complete_pack, open_pack
from .source import PackSource

logger = logging.getLogger(__name__)

__all__ = ["PackCache", "Shape"]

#: A pack's volume shape ``(Z, Y, X)``.
Shape = tuple[int, int, int]


class PackCache:
    """The packs ``0 .. n_packs - 1`` of `source` and `config` in `format`, cached under `root`.

    Parameters
    ----------
    root : Path
        Cache root (see the module docstring for the layout).
    source : PackSource
        What the grains come from; its identity (sample name and seed, scan
        files' paths, sizes and modification times, or the hash of the
        library's ``library.json``) is taken now.
    n_packs : int
        Number of packs; pack ``k`` is the same whatever `n_packs` is.
    config : PackConfig
        Pack configuration, seed included.
    format : {"tiff", "zarr"}
        Pack format, as `synthpack.store.pack.pack_format` names it.

    Attributes
    ----------
    directory : Path
        ``root/packs-<key>``.
    paths : list of Path
        The pack directories ``directory/pack_0000``, ...
    """

    def __init__(self, root: Path, source: PackSource, n_packs: int, config: PackConfig, format: str) -> None:
        self.root = root
        self.source = source
        self.config = config
        self.format = format
        identity = source.identity()
        self._library_key = {"source": identity, "library": config.to_dict()["library"], "synthpack": __version__}
        self._pack_key = {"source": identity, "config": config.to_dict(), "format": format, "synthpack": __version__}
        self.directory = root / f"packs-{_digest(self._pack_key)}"
        self.paths = [self.directory / pack_name(k) for k in range(n_packs)]

    def check(self) -> list[Shape | None]:
        """Shape of each cached pack; None where it is missing, incomplete, corrupt or stale (logged).

        A pack's checksums and labels are verified (`synthpack.store.pack.verify_pack`)
        the first time it is seen and again whenever one of its files changes size
        or modification time; the stamps of verified packs are kept in
        ``verified.json``, so an unchanged cache is not read again.
        """
        config = json.loads(json.dumps(self.config.to_dict()))  # as the manifest stores it
        stamps_path = self.directory / "verified.json"
        try:
            verified = json.loads(stamps_path.read_text())
        except (OSError, ValueError):
            verified = {}
        shapes = []
        for path in self.paths:
            stamp = _stamp(path)
            shape = _usable_pack_shape(path, config, verify=verified.get(path.name) != stamp)
            if shape is not None:
                verified[path.name] = stamp
            else:
                verified.pop(path.name, None)
            shapes.append(shape)
        if self.directory.is_dir():
            with atomic_file(stamps_path) as tmp:
                tmp.write_text(strict_json(verified, indent=1, sort_keys=True))
        return shapes

    def build(self, shapes: Sequence[Shape | None], *, progress: bool = False) -> list[Shape]:
        """Rebuild the packs that `check` found unusable (`shapes` is its result); return every pack's shape.

        Unusable pack directories are removed first; the packs are built as Dask
        tasks (`synthpack.pipeline.generate.generate_packs`), which skips complete ones.
        """
        for path, shape in zip(self.paths, shapes):
            if shape is None and path.is_symlink():
                path.unlink()  # the link only: what it points to is not the cache's to delete
            elif shape is None and path.exists():
                shutil.rmtree(path)
        generate_packs(self._library(progress), self.directory, len(self.paths), self.config, format=self.format,
                       source=self.source.describe(), progress=progress,
                       overwrite=True)  # the cache's own folder, even while it holds no pack
        _write_key(self.directory, self._pack_key)
        built = self.check()
        if any(shape is None for shape in built):
            raise SynthpackInputError(f"packs in {self.directory} were built but cannot be read back: "
                                      "check the disk (space, permissions) and try again")
        return built  # type: ignore[return-value]

    def _library(self, progress: bool) -> ParticleLibrary:
        """The source's particle library: loaded, from the cache, or built from the scan and cached."""
        if self.source.kind == "library":
            return ParticleLibrary.load(self.source.paths[0])
        directory = self.root / f"library-{_digest(self._library_key)}"
        if (directory / "library").exists():
            try:
                return ParticleLibrary.load(directory / "library")
            except SynthpackInputError as error:
                logger.warning("cached library is unusable (%s): it will be rebuilt", error)
        scan = self.source.read_scan()
        logger.info("building the particle library of %s into %s", self.source.describe(), directory)
        library = ParticleLibrary.from_scan(scan, **vars(self.config.library), progress=progress)
        library.save(directory / "library")
        _write_key(directory, self._library_key)
        return library


def _digest(data: dict) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def _write_key(directory: Path, key: dict) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    with atomic_file(directory / "key.json") as tmp:
        tmp.write_text(strict_json(key, indent=1, sort_keys=True))


def _stamp(path: Path) -> dict[str, list[int]]:
    """Size and modification time (ns) of every file of the pack at `path`."""
    if not path.is_dir():
        return {}
    files = sorted(p for p in path.rglob("*") if p.is_file())
    return {p.relative_to(path).as_posix(): [p.stat().st_size, p.stat().st_mtime_ns] for p in files}


def _usable_pack_shape(path: Path, config: dict, *, verify: bool) -> Shape | None:
    """Shape of the cached pack at `path`, or None when it is missing, incomplete, corrupt or stale.

    With `verify`, the checksums of its files and its labels are checked too.
    """
    if not path.exists():
        return None
    problem = None
    if path.is_symlink():
        problem = "a symbolic link, not a pack the cache wrote"
    elif not is_complete_pack(path):
        problem = "incomplete"
    else:
        try:
            pack = open_pack(path, verify=verify)
        except SynthpackInputError as error:
            problem = str(error)
        else:
            if pack.shape != tuple(pack.manifest.get("shape", ())):
                problem = f"volumes of shape {pack.shape}, manifest says {pack.manifest.get('shape')}"
            elif pack.manifest.get("config") != config:
                problem = "built with another config"
            elif pack.labels.dtype.kind not in "iu":
                problem = f"labels of dtype {pack.labels.dtype}"
    if problem is not None:
        logger.warning("cached pack %s is unusable (%s): it will be rebuilt", path, problem)
        return None
    return pack.shape
