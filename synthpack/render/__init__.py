"""Render: a new tomogram and label volume from the grains' smooth surfaces at their poured poses (paper 3.4).

Modules, one job each, from the whole render down:

====================  ================================================================================
``chunked``           `reconstruct`: the whole grid, chunk by chunk, with a chunk renderer
``numpy_render``      `render_chunk`: one chunk on the CPU, at the voxels each grain can change
``torch_render``      `TorchRenderer`: one chunk on a torch device (a CUDA GPU); `resolve_device`
``canvas``            `Canvas`: a chunk as grains are drawn on it (claims, partial-volume composite),
                      one code for NumPy and torch
``kernel``            `resolve_kernel`: each grain in one compiled pass over its box (numba), or with SciPy
``background``        `Background`: pore level, pore texture and tube wall; `background_values`
``crops``             `RenderCrop`, `prepare_crops`: the library crops as the render takes them
``poses``             `pose_maps`: each placement's affine map into its crop and the box it reaches
``config``            `ReconstructConfig`: the render's settings
``grid``              `Grid`: the output voxel grid
``surface``           `Surface`: each grain's smooth surface (a smoothed signed distance), made once per grain
``pore_texture``      `PoreTextureConfig`: the pore phase's seeded, correlated texture
``partial_volume``    `PartialVolume`: each grain's occupancy of the voxels, its intensities prepared once
``segmented_labels``  `SegmentedLabels`: the labels redrawn as a threshold segmentation of the scan draws them
``crop_cache``        what is prepared once per library grain, kept for the next render in this process
====================  ================================================================================
"""

from __future__ import annotations

from .._shared.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "Background": ".background",
    "Canvas": ".canvas",
    "Grid": ".grid",
    "PartialVolume": ".partial_volume",
    "PoreTextureConfig": ".pore_texture",
    "PoseMaps": ".poses",
    "ReconstructConfig": ".config",
    "Surface": ".surface",
    "RenderCrop": ".crops",
    "SegmentedLabels": ".segmented_labels",
    "TorchRenderer": ".torch_render",
    "background_values": ".background",
    "pose_maps": ".poses",
    "prepare_crops": ".crops",
    "reconstruct": ".chunked",
    "render_chunk": ".numpy_render",
    "resolve_kernel": ".kernel",
    "resolve_device": ".torch_render",
})
