"""Post-processing of a rendered pack: what the config's ``postprocess`` means, resolved in one place.

`resolve_postprocessing` turns the ``postprocess`` value of a pack config and the
source scan's statistics (`~synthpack.source.SourceStatistics`) into the artefact
pipeline to apply to the clean pack, and the values to record in the pack's
manifest:

================  ===========================================================================
``default``       `~synthpack.artefacts.default_postprocessing` scaled to the source's
                  grain-pore contrast: light blur, weak rings half the time, Gaussian noise
``none``          nothing (an empty pipeline)
``match_source``  Gaussian noise that brings the clean pack to the source's noise level
                  (measured on the pack's central slices, at most `NOISE_SAMPLE_VOXELS` voxels;
                  variances add, `~synthpack.artefacts.noise_to_add`)
``calibrated``    the source's image formation, fitted in the pack's bulk region
                  (`bulk_region`; `~synthpack.artefacts.calibrate`): a Gaussian PSF that gives
                  the source's edge width, then noise with the source's noise power spectrum
                  in grains and pores, less what the clean pack already holds; the fit is
                  recorded under ``calibration`` (the render's partial volume, also fitted
                  to the source, under ``partial_volume``)
a list            artefact transforms (`~synthpack.artefacts.from_config`)
================  ===========================================================================

It comes after the render and the artefacts, and before the pack writers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .artefacts import Compose, calibrate, default_postprocessing, from_config, noise_to_add
from .errors import SynthpackInputError
from .reconstruct import Grid
from .source.noise import estimate_noise
from .source.statistics import SourceStatistics

__all__ = [
    "MIN_REGION_VOXELS",
    "NOISE_SAMPLE_VOXELS",
    "POSTPROCESS_MODES",
    "Postprocessing",
    "bulk_region",
    "check_postprocess",
    "resolve_postprocessing",
]

#: The named post-processing modes; a list of artefact transforms is the alternative.
POSTPROCESS_MODES = ("default", "none", "match_source", "calibrated")
#: ``match_source`` measures the clean pack's noise on at most about this many central voxels.
NOISE_SAMPLE_VOXELS = 1 << 24
#: A bulk region needs at least this many voxels to be measured.
MIN_REGION_VOXELS = 1000


@dataclass(frozen=True)
class Postprocessing:
    """A resolved post-processing: the pipeline, and what to record of how it was chosen.

    Attributes
    ----------
    pipeline : Compose
        The transforms to apply to the clean pack (seeded at application).
    record : dict
        Entries for the pack manifest: ``{"calibration": ...}`` (every fitted and
        matched value) for ``calibrated``, empty otherwise.
    """

    pipeline: Compose
    record: dict[str, Any] = field(default_factory=dict)


def _calibration_targets(statistics: SourceStatistics) -> dict[str, Any]:
    """Keyword arguments of `~synthpack.artefacts.calibrate` from the source statistics.

    A phase without a measured spectrum or noise level (too thin for a patch) takes the other phase's.
    """
    spectra = {"grains": statistics.nps_grains or statistics.nps_pores,
               "pores": statistics.nps_pores or statistics.nps_grains}
    grain_std, pore_std = statistics.noise_grain_std, statistics.noise_pore_std
    levels = {"grains": grain_std if grain_std is not None else pore_std,
              "pores": pore_std if pore_std is not None else grain_std}
    edges = (statistics.edge_width, statistics.edge_sigma, statistics.edge_shift)
    if any(value is None for value in edges) or spectra["pores"] is None:
        raise SynthpackInputError(
            "postprocess: calibrated needs the source scan's edge width, blur and noise spectrum, which could not "
            "be measured "
            "when the particle library was built (it needs grain and pore interiors, grains brighter than pores): "
            "rebuild it from such a scan with `synthpack library build`, or choose another postprocess"
        )
    return {"target_sigma": float(statistics.edge_sigma), "target_shift": float(statistics.edge_shift),
            "target_power": spectra, "target_phase_noise": levels, "target_edge_width": float(statistics.edge_width),
            "target_noise": float(statistics.noise_std), "pore_level": statistics.pore_mean,
            "grain_level": statistics.grain_mean}


def check_postprocess(postprocess: str | list, statistics: SourceStatistics) -> None:
    """Refuse, before any work, a post-processing that `statistics` cannot support.

    Raises
    ------
    SynthpackInputError
        For ``calibrated`` when the source's edge or noise spectrum was not measured.
    """
    if postprocess == "calibrated":
        _calibration_targets(statistics)


def resolve_postprocessing(
    postprocess: str | list,
    statistics: SourceStatistics,
    *,
    clean: Any,
    labels: Any,
    grid: Grid,
    packing_region: dict[str, float],
) -> Postprocessing:
    """The post-processing of one rendered pack (see the module docstring for the modes).

    Parameters
    ----------
    postprocess : str or list
        The config value: one of `POSTPROCESS_MODES`, or a list of artefact transform configs.
    statistics : SourceStatistics
        Of the source scan (from the particle library).
    clean : array of float32, shape (Z, Y, X)
        The clean pack (NumPy or Zarr); read by ``match_source`` and ``calibrated`` only.
    labels : array of int32, shape (Z, Y, X)
        Its labels (0 = pore, tube or outside).
    grid : Grid
        Where the volumes sit in the world frame.
    packing_region : dict
        ``radius``, ``z_min``, ``z_max`` of the pour's bulk sub-cylinder, physical
        units (``PourChecks.packing_region``); ``calibrated`` measures there.

    Returns
    -------
    Postprocessing

    Raises
    ------
    SynthpackInputError
        For ``calibrated`` without the source's edge width, or a pack without a bulk region.
    """
    if postprocess == "default":
        return Postprocessing(default_postprocessing(contrast=statistics.contrast))
    if postprocess == "none":
        return Postprocessing(Compose([]))
    if postprocess == "match_source":
        window = _central_slab(labels.shape)
        clean_noise = estimate_noise(clean[window], labels[window]).std
        return Postprocessing(Compose([noise_to_add(statistics.noise_std, clean_noise)]))
    if postprocess == "calibrated":
        targets = _calibration_targets(statistics)
        region = bulk_region(grid.shape, grid.origin, grid.voxel_size, packing_region)
        calibration = calibrate(clean, labels, region, **targets)
        return Postprocessing(calibration.pipeline(), {"calibration": calibration.to_dict()})
    if isinstance(postprocess, list):
        return Postprocessing(from_config(postprocess))
    raise SynthpackInputError(
        f"postprocess must be one of {', '.join(POSTPROCESS_MODES)} or a list of artefact transforms, "
        f"got {postprocess!r}"
    )


def _central_slab(shape: tuple[int, ...], max_voxels: int = NOISE_SAMPLE_VOXELS) -> tuple[slice, ...]:
    """The central slices of a volume of `shape` holding at most about `max_voxels` voxels (at least one slice)."""
    n = min(shape[0], max(1, max_voxels // math.prod(shape[1:])))
    start = (shape[0] - n) // 2
    return (slice(start, start + n), slice(None), slice(None))


def bulk_region(
    shape: tuple[int, int, int],
    origin: tuple[float, float, float],
    voxel_size: tuple[float, float, float],
    packing_region: dict[str, float],
) -> np.ndarray:
    """Voxels of a pack grid inside the bulk sub-cylinder of its pour.

    The sub-cylinder is the one the pour's packing-fraction check uses
    (`synthpack.physics.checks`): one median grain diameter from the tube wall
    and floor, two below the top of the pack. Calibration fits there, and the
    realism report measures there.

    Parameters
    ----------
    shape : tuple of 3 int
        ``(Z, Y, X)`` of the pack volumes.
    origin : tuple of 3 float
        World position ``(z, y, x)`` of the centre of voxel ``(0, 0, 0)``, physical units.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)``, physical units.
    packing_region : dict
        ``radius``, ``z_min``, ``z_max`` of the sub-cylinder about the world z axis,
        physical units (``PourChecks.packing_region``).

    Returns
    -------
    ndarray of bool, shape (Z, Y, X)
        True for voxels whose centre lies in the sub-cylinder.

    Raises
    ------
    SynthpackInputError
        If fewer than `MIN_REGION_VOXELS` voxels lie in it (a pack too shallow or too
        narrow to have a bulk).
    """
    z = origin[0] + np.arange(shape[0]) * voxel_size[0]
    y = origin[1] + np.arange(shape[1]) * voxel_size[1]
    x = origin[2] + np.arange(shape[2]) * voxel_size[2]
    in_disc = np.hypot(y[:, None], x[None, :]) <= packing_region["radius"]
    in_height = (z >= packing_region["z_min"]) & (z <= packing_region["z_max"])
    region = in_height[:, None, None] & in_disc[None, :, :]
    if np.count_nonzero(region) < MIN_REGION_VOXELS:
        raise SynthpackInputError(
            f"the pack has no bulk to measure ({np.count_nonzero(region)} voxels lie one grain diameter "
            "from the tube wall and floor and two below its top): pour more grains (pour.n_particles) "
            "or use a wider tube (pour.tube_radius)"
        )
    return region
