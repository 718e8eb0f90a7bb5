"""The pipeline: configuration, one pack built (pour -> render -> post-process -> store), many on Dask.

Modules, one job each:

============  ================================================================================
``config``    `PackConfig`: every stage's settings, from YAML or a dict, validated
``generate``  `build_pack`, `generate_packs`: from a library to packs on disk
``runner``    `run_packs`: the builds of many packs as Dask tasks
============  ================================================================================
"""

from __future__ import annotations

from .._shared.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "GrainsConfig": ".config",
    "PackConfig": ".config",
    "build_pack": ".generate",
    "generate_pack": ".generate",
    "generate_packs": ".generate",
    "load_config": ".config",
    "pack_seed": ".generate",
    "run_packs": ".runner",
})
