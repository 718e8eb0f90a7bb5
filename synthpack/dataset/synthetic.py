"""`SyntheticParticlePackDataset`: slices of synthetic packs, built into the pack cache on first use."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from torch.utils.data import get_worker_info

from ..pipeline.config import PackConfig, load_config
from ..errors import SynthpackInputError
from ..store.pack import Pack, open_pack, pack_format
from .base import SliceDataset, check_seed
from .cache import PackCache
from .source import PackSource

__all__ = ["SyntheticParticlePackDataset"]

class SyntheticParticlePackDataset(SliceDataset):
    """Slices of synthetic particle packs, built on demand and cached on disk.

    Parameters
    ----------
    root : path-like
        Cache directory. Packs go to ``root/packs-<key>/pack_0000, ...`` and a
        library built from a scan to ``root/library-<key>/library``; each
        ``<key>`` folder has a ``key.json`` recording what its key covers.
    source : str, (path, path) or path-like
        ``"large"`` or ``"small"`` (a built-in sample scan, seed 0), a
        ``(tomogram_path, labels_path)`` pair of a labelled scan (read with
        `synthpack.io.read_scan`), or a particle library directory (written by
        `ParticleLibrary.save`; then the config's ``library`` section is unused).
        A string equal to a sample name means the sample; pass a Path for a
        library folder of that name.
    n_packs : int
        Number of packs; pack ``k`` is the same whatever `n_packs` is, so
        raising it builds only the new packs.
    split : {"train", "test", "all"}
        ``"test"``: the central 20% of each pack's slices along `axis`;
        ``"train"``: the rest.
    axis : {0, 1, 2}
        Slicing axis of the (Z, Y, X) packs; 0 = along the tube.
    seed : int, optional
        Run seed of the packs (replaces ``config.seed``; default: ``config.seed``)
        and base seed of the artefact transforms.
    config : PackConfig, dict or path-like, optional
        Pack configuration (a YAML file path is read with `load_config`);
        default ``PackConfig()``.
    transform : callable, artefact transform or list of them, optional
        See `synthpack.dataset` for the order: artefact transforms act on the
        NumPy slice with per-item, per-epoch seeds; other callables are called as
        ``image, target = transform(image, target)``.
    postprocess : bool
        True: the post-processed tomogram (noise, blur as configured); False: the
        clean tomogram before post-processing (the paper's "without
        post-processing" arm). Both come from the same cached packs.
    build : bool
        Build (or check) the packs now instead of on first use.
    progress : bool
        Show progress bars while building.
    dense_masks : bool
        True: ``target["masks"]`` (N, H, W). False: the compact
        ``target["instance_map"]`` (H, W) instead, N times cheaper to send from
        DataLoader workers; :func:`expand_masks` turns it into ``masks``.
    format : {"tiff", "zarr", "ome-zarr"}
        Format of the cached packs (`synthpack.store.pack.PACK_FORMATS`). Zarr packs
        (OME-Zarr stores; ``"ome-zarr"`` is another name) are built chunk by
        chunk, for volumes larger than memory, and an item reads only the Zarr
        chunks its slice crosses; the voxels are the same in both formats.

    Notes
    -----
    When packs are built: on `build` (or ``build=True``) or on the first
    ``len()`` / item access in the main process, which is before any DataLoader
    worker asks for an item (a DataLoader calls ``len()`` in the main process
    before it hands out indices). DataLoader workers never build: they only read
    the cache, and raise if it is missing (call ``dataset.build()`` first when
    you use a sampler that never calls ``len()``). Two separate programs building
    the same cache at once do not corrupt it (packs are written atomically) but
    may both do the work. The cache itself is `synthpack.dataset.cache.PackCache`.

    The cache key is a hash of the full config (seed included), the source's
    identity (sample name and seed; the scan files' paths, sizes and modification
    times; or the hash of the library's ``library.json``), the pack format and
    the synthpack version, so a changed config or source never returns stale
    packs. A cached pack that is incomplete, corrupt (a TIFF that no longer
    memory-maps, e.g. truncated), of the wrong shape or of another config is
    rebuilt, never returned.
    """

    def __init__(
        self,
        root: str | os.PathLike,
        source: str | os.PathLike | tuple,
        n_packs: int = 1,
        split: str = "train",
        axis: int = 0,
        seed: int | None = None,
        config: PackConfig | dict | str | os.PathLike | None = None,
        transform: Any = None,
        postprocess: bool = True,
        *,
        build: bool = False,
        progress: bool = False,
        dense_masks: bool = True,
        format: str = "tiff",
    ) -> None:
        if isinstance(n_packs, bool) or not isinstance(n_packs, int) or n_packs < 1:
            raise SynthpackInputError(f"n_packs must be a positive integer, got {n_packs!r}")
        format = pack_format(format)
        config = _as_config(config)
        if seed is not None:
            config = config.replace(seed=check_seed(seed, "seed"))
        super().__init__(split, axis, config.seed, transform, dense_masks)
        self.root = Path(root).expanduser()
        self.source = PackSource.parse(source)
        self.n_packs = n_packs
        self.config = config
        self.postprocess = bool(postprocess)
        self.progress = progress
        self.format = format
        self._cache = PackCache(self.root, self.source, n_packs, config, format)
        self._pack_paths: list[Path] | None = None
        if build:
            self.build()

    @property
    def cache_dir(self) -> Path:
        """The cache folder of these packs, ``root/packs-<key>``."""
        return self._cache.directory

    @property
    def pack_paths(self) -> list[Path]:
        """The pack directories, ``cache_dir/pack_0000``, ... (built if needed)."""
        self._ready()
        return list(self._pack_paths)  # type: ignore[arg-type]

    def build(self) -> SyntheticParticlePackDataset:
        """Build the missing or unusable packs now (as Dask tasks, see `generate_packs`); return the dataset."""
        self._ready()
        return self

    def _ready(self) -> None:
        if self._pack_paths is not None:
            return
        shapes = self._cache.check()
        if any(shape is None for shape in shapes):
            if get_worker_info() is not None:
                raise SynthpackInputError(
                    f"the packs in {self.cache_dir} are not built, and DataLoader workers never build "
                    "them: call dataset.build() (or len(dataset)) before iterating the DataLoader"
                )
            shapes = self._cache.build(shapes, progress=self.progress)
        self._index(shapes)  # type: ignore[arg-type]
        self._pack_paths = self._cache.paths

    def _volumes(self, k: int) -> tuple[Any, Any]:
        opened = self._opened_cache()
        if k not in opened:
            opened[k] = open_pack(self._pack_paths[k])  # type: ignore[index]
        pack: Pack = opened[k]
        return (pack.tomogram if self.postprocess else pack.clean), pack.labels

    def describe_source(self) -> str:
        return f"packs of {self.source.describe()}"

    def _repr_lines(self) -> list[str]:
        lines = [f"Root location: {self.root}", f"Source: {self.source.describe()}", f"Packs: {self.n_packs}"]
        if self._pack_paths is None:
            lines.insert(0, "Number of datapoints: not known yet (packs are built or checked on first use)")
        else:
            lines.append(f"Slices per pack along axis {self.axis}: {self._n_slices}")
        return [*lines, f"Cache: {self.cache_dir}", f"Format: {self.format}", f"Postprocess: {self.postprocess}"]


def _as_config(config: PackConfig | dict | str | os.PathLike | None) -> PackConfig:
    """`config` as a PackConfig: as is, from a dict, from a YAML file, or the default."""
    if config is None or isinstance(config, PackConfig):
        return config or PackConfig()
    if isinstance(config, dict):
        return PackConfig.from_dict(config)
    if isinstance(config, (str, os.PathLike)):
        return load_config(config)
    raise SynthpackInputError(f"config must be a PackConfig, a dict or a YAML file path, got {type(config).__name__}")
