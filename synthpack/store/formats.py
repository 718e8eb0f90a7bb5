"""The volume formats of a pack: the one list ``--format``, `stage_pack`, the generators and the dataset accept.

Kept apart from `synthpack.store.pack` (which imports Zarr) so the command line builds its
options without importing the storage libraries.
"""

from __future__ import annotations

from ..errors import SynthpackInputError

__all__ = ["PACK_FORMATS", "pack_format"]

#: Volume formats of a pack: ``"ome-zarr"`` is another name of ``"zarr"``, whose packs
#: are OME-Zarr stores (the manifest records ``"zarr"``).
PACK_FORMATS = ("tiff", "zarr", "ome-zarr")
_ALIASES = {"ome-zarr": "zarr"}


def pack_format(format: str) -> str:
    """The name a pack format is recorded under: ``"tiff"`` or ``"zarr"`` (for ``"zarr"`` and ``"ome-zarr"``).

    Raises
    ------
    SynthpackInputError
        If `format` is not one of :data:`PACK_FORMATS`.
    """
    if format not in PACK_FORMATS:
        raise SynthpackInputError(f"pack format must be one of {', '.join(PACK_FORMATS)}, got {format!r}")
    return _ALIASES.get(format, format)
