"""The particle library: every grain of a labelled scan, cropped, meshed and kept with the source's statistics.

Modules, one job each:

=============  ================================================================================
``particles``  `extract_particles`: one pass of find_objects -> clean crops, masks, sizes, border flags
``meshing``    `mesh_from_mask`: marching cubes + decimation -> watertight meshes
``sampling``   `window_weights`: how often a pour draws each grain (the field of view's size bias undone)
``core``       `ParticleLibrary` (versioned on disk) and `LibraryConfig`
``deform``     `pack_grains`: one free-form-deformed grain per placement
=============  ================================================================================
"""

from __future__ import annotations

from .._shared.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "DeformConfig": ".deform",
    "LibraryConfig": ".core",
    "PackGrains": ".deform",
    "Particle": ".particles",
    "ParticleLibrary": ".core",
    "extract_particles": ".particles",
    "mesh_from_mask": ".meshing",
    "pack_grains": ".deform",
    "window_weights": ".sampling",
})
