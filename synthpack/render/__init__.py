"""Render: a new tomogram and label volume from the grains' voxels at their poured poses (paper 3.4).

Modules, one job each:

==================  ================================================================================
``reconstruct``     `reconstruct`: the grid, background and pose maps, rendered chunk by chunk
``partial_volume``  each grain's occupancy (partial volume) from its crop, prepared once per grain
``pore_texture``    `PoreTexture`: the pore phase's seeded, correlated texture
``torch_render``    the same render on a CUDA GPU
==================  ================================================================================
"""

from __future__ import annotations

from .._shared.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "Background": ".reconstruct",
    "Grid": ".reconstruct",
    "PartialVolume": ".partial_volume",
    "PoreTexture": ".pore_texture",
    "ReconstructConfig": ".reconstruct",
    "resolve_device": ".torch_render",
})
