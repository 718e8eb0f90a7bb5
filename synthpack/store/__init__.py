"""Packs on disk: volumes, placements and manifest, written atomically (TIFF or OME-Zarr).

Modules, one job each:

=============  ================================================================================
``formats``    `PACK_FORMATS`: the one list ``--format`` and every ``format=`` accept
``pack``       `stage_pack`, `open_pack`, `verify_pack`: a pack folder and its manifest
``zarr_pack``  a Zarr pack's OME-Zarr store: levels, label image, clean image
=============  ================================================================================
"""

from __future__ import annotations

from .._shared.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "PACK_FORMATS": ".formats",
    "Pack": ".pack",
    "find_packs": ".pack",
    "is_complete_pack": ".pack",
    "open_pack": ".pack",
    "stage_pack": ".pack",
    "verify_pack": ".pack",
})
