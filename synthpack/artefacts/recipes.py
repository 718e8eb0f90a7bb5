"""Post-processing of a rendered pack: what the config's ``postprocess`` means, resolved in one place.

`resolve_postprocessing` turns the ``postprocess`` value of a pack config and the
source scan's statistics (`~synthpack.source.SourceStatistics`) into the artefact
pipeline to apply to the clean pack, and the values to record in the pack's
manifest:

================  ===========================================================================
``calibrated``    the default (`~synthpack.pipeline.config.PackConfig`): the source's image formation,
                  fitted in the pack's bulk region (`bulk_region`; `~synthpack.artefacts.calibrate`):
                  a Gaussian PSF that gives the source's edge spread, then noise with the
                  source's noise power spectrum and fine texture in grains and pores, less what
                  the clean pack already holds, then the source's cupping and rings where it
                  shows them (measured, fixed, about the tube axis), then the source's grey-level
                  grid where it holds whole numbers; all recorded under ``calibration``
                  (the render's partial volume, also fitted to the source, under
                  ``partial_volume``; its tube wall under ``wall``). Where
                  it cannot be fitted (the source's edges or noise spectrum were not measured,
                  the pack has no bulk region, or its bulk no edges), ``match_source`` instead,
                  with a warning, and the reason recorded under ``postprocess_fallback``
``match_source``  Gaussian noise that brings the clean pack to the source's noise level
                  (measured on the pack's central slices, at most `NOISE_SAMPLE_VOXELS` voxels;
                  variances add, `~synthpack.artefacts.noise_to_add`); recorded under
                  ``noise_match``
``generic``       `~synthpack.artefacts.generic_postprocessing` scaled to the magnitude of the
                  source's grain-pore contrast: light blur, weak rings half the time, Gaussian
                  noise of 3-8 % of the contrast; fitted to nothing
``randomised``    domain randomisation (in the spirit of SynthSeg): every pack draws its own
                  image formation, from the pack's seed, within wide ranges about the
                  ``calibrated`` values (about ``match_source``'s noise and no artefacts where
                  the fit is not possible): see `RANDOMISED_RANGES` and below; the centre and
                  every drawn value recorded under ``randomised``
``none``          nothing (an empty pipeline)
a list            artefact transforms (`~synthpack.artefacts.from_config`)
================  ===========================================================================

``randomised`` draws, per pack (`RANDOMISED_RANGES`; ``c`` is the calibrated value, ``C``
the source's grain-pore contrast), and applies in this order:

- blur: a Gaussian PSF of sigma ``U(0.5, 2) * max(c, 0.5)`` voxels;
- noise: its level ``U(0.5, 2)`` times the calibrated added noise (standard deviation,
  per phase); its colour the calibrated spectrum or white, half the time each;
- cupping: strength ``c + U(-0.1, 0.1)`` (``c`` = 0 where the source shows none),
  keeping the mean level;
- rings: ``U(0, 10)`` rings at random radii, amplitude up to ``U(0, 2)`` times the
  source's largest ring (at least 2% of ``C``), FWHM ``U(1, 3)`` voxels;
- contrast and gamma (`~synthpack.artefacts.ContrastGamma` between the source's
  phase levels): contrast ``U(0.7, 1.3)``, gamma log-uniform in ``[2/3, 3/2]``.

The mode a pack got is recorded under ``postprocess_mode`` (``custom`` for a list).
Grains may be brighter or darker than pores: every mode works with the signed
contrast. (``default``, the name of ``generic`` before synthpack 0.3.0, is read
by the config as the default, with a warning.)

It comes after the render and the artefacts, and before the pack writers.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import (
    BeamHardening,
    Calibration,
    ColouredNoise,
    Compose,
    ContrastGamma,
    GaussianBlur,
    GaussianNoise,
    RingArtefacts,
    RoundLevels,
    calibrate,
    calibration_halo,
    from_config,
    generic_postprocessing,
    measured_slices,
    noise_to_add,
)
from .._shared.seeds import generator
from .band_map import BandMap
from ..errors import SynthpackInputError
from ..render.grid import Grid
from ..measure.noise_estimate import estimate_noise
from ..measure.phase_histograms import BAND_KEYS
from ..measure.spectrum import NPS_PATCH, ring_frequencies, white_ring_powers
from ..physics.checks import bulk_shortfall
from ..source.statistics import SourceStatistics

logger = logging.getLogger(__name__)

__all__ = [
    "MIN_REGION_VOXELS",
    "NOISE_SAMPLE_VOXELS",
    "POSTPROCESS_MODES",
    "Postprocessing",
    "RANDOMISED_RANGES",
    "bulk_parts",
    "bulk_region",
    "check_postprocess",
    "resolve_postprocessing",
]

#: The named post-processing modes; a list of artefact transforms is the alternative.
POSTPROCESS_MODES = ("calibrated", "match_source", "generic", "randomised", "none")
#: The ranges ``randomised`` draws from, per pack (see the module docstring): factors on the calibrated
#: value (``blur_factor``, ``noise_factor``, ``ring_factor``), offsets (``cupping_offset``), absolute values
#: (``n_rings``, ``ring_width`` voxels, ``contrast``, ``gamma``), floors (``min_blur`` voxels,
#: ``min_ring_amplitude`` as a fraction of the contrast) and the chance of white noise (``white_noise``).
RANDOMISED_RANGES = {
    "blur_factor": (0.5, 2.0), "min_blur": 0.5,
    "noise_factor": (0.5, 2.0), "white_noise": 0.5,
    "cupping_offset": (-0.1, 0.1),
    "n_rings": (0, 10), "ring_factor": (0.0, 2.0), "min_ring_amplitude": 0.02, "ring_width": (1.0, 3.0),
    "contrast": (0.7, 1.3), "gamma": (2.0 / 3.0, 1.5),
}
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
    band_map : BandMap or None
        Applied after `pipeline`, with the pack's labels (`~synthpack.artefacts.band_map.apply_band_map`):
        ``calibrated``'s, where its guard kept one.
    band_map_rounding : RoundLevels or None
        The source's grey-level grid, which the band map's output is rounded to (the calibration's
        `~synthpack.artefacts.calibrate.Calibration.rounding`: the pipeline then leaves it to the map); None: none.
    record : dict
        Entries for the pack manifest: ``postprocess_mode`` (the mode applied:
        one of `POSTPROCESS_MODES`, or ``custom``), and every fitted or matched
        value: ``calibration`` for ``calibrated``, ``noise_match`` for
        ``match_source``; ``postprocess_fallback`` (why) where ``calibrated``
        fell back to ``match_source``.
    """

    pipeline: Compose
    record: dict[str, Any] = field(default_factory=dict)
    band_map: BandMap | None = None
    band_map_rounding: RoundLevels | None = None


@functools.cache
def _warn_once(message: str) -> None:
    """Log `message` as a warning, once per process (a run checks before its packs, then each pack)."""
    logger.warning(message)


def _fallback(reason: str, mode: str = "calibrated") -> None:
    """Warn, once, that `mode` cannot be fitted because of `reason` and what it does instead."""
    instead = ("using match_source (the source's noise level, no fitted blur)"
               if mode == "calibrated" else "drawing about match_source's noise level, white, and a 0.5 voxel blur")
    _warn_once(f"postprocess: {mode} cannot be fitted ({reason}): {instead}")


def _uncalibratable(statistics: SourceStatistics) -> str | None:
    """Why no pack of a source with `statistics` can be calibrated, or None."""
    edges = (statistics.edge_width, statistics.edge_sigma, statistics.edge_shift)
    if any(value is None for value in edges):
        return ("the source scan's edge width could not be measured when the particle library was built: it "
                "needs grain and pore interiors of different levels; rebuild the library from such a scan")
    return None


def _check_mode(postprocess: str | list) -> None:
    """Refuse a value that is neither one of `POSTPROCESS_MODES` nor a list."""
    if not (isinstance(postprocess, list) or postprocess in POSTPROCESS_MODES):
        raise SynthpackInputError(
            f"postprocess must be one of {', '.join(POSTPROCESS_MODES)} or a list of artefact transforms, "
            f"got {postprocess!r}"
        )


def _calibration_targets(statistics: SourceStatistics) -> dict[str, Any]:
    """Keyword arguments of `~synthpack.artefacts.calibrate` from the source statistics.

    A phase without a measured noise level takes the other phase's. A phase without a
    measured spectrum (too thin for a patch) gets white noise at its noise level (or the
    scan's, where neither phase's is measured): the other phase's spectrum may hold that
    phase's texture (a cement paste's sand and voids), which is not the noise of the
    first. A scan whose grains and pores are both too thin (small grains, narrow pores)
    is calibrated with white noise in both: its edges and levels are still fitted.
    """
    grain_std, pore_std = statistics.noise_grain_std, statistics.noise_pore_std
    levels = {"grains": grain_std if grain_std is not None else pore_std,
              "pores": pore_std if pore_std is not None else grain_std}
    n_rings = len(ring_frequencies(NPS_PATCH)) - 1  # ring 0, the patch mean, is not kept
    spectra = {phase: tuple(measured) if measured is not None else tuple(white_ring_powers(
        (levels[phase] if levels[phase] is not None else statistics.noise_std) ** 2, n_rings))
        for phase, measured in (("grains", statistics.nps_grains), ("pores", statistics.nps_pores))}
    rings = None if statistics.ring_radii is None else (
        statistics.ring_radii, statistics.ring_amplitudes, statistics.ring_width)
    return {"target_sigma": float(statistics.edge_sigma), "target_shift": float(statistics.edge_shift),
            "target_power": spectra, "target_nps_depth": statistics.nps_depth,
            "target_phase_noise": levels, "target_edge_width": float(statistics.edge_width),
            "target_noise": float(statistics.noise_std), "pore_level": statistics.pore_mean,
            "grain_level": statistics.grain_mean, "cupping_strength": statistics.cupping_strength, "rings": rings,
            "target_histograms": {"grains": statistics.histogram_grains, "pores": statistics.histogram_pores,
                                  "edges": statistics.histogram_edges},
            "target_semivariogram": {"grains": statistics.semivariogram_grains, "pores": statistics.semivariogram_pores},
            "target_steepness": statistics.edge_steepness,
            "target_bands": None if statistics.band_histograms is None else dict(zip(BAND_KEYS, statistics.band_histograms)),
            "target_patches": statistics.patch_reference, "target_spectra": statistics.volume_spectra,
            "grey_levels": statistics.grey_levels}


def check_postprocess(postprocess: str | list, statistics: SourceStatistics) -> None:
    """Check, before any work, a post-processing against the source statistics.

    Warns (once) when ``calibrated`` will fall back to ``match_source`` for every
    pack because the source's edge width was not measured.

    Raises
    ------
    SynthpackInputError
        For a value that is neither one of `POSTPROCESS_MODES` nor a list.
    """
    _check_mode(postprocess)
    if postprocess in ("calibrated", "randomised"):
        reason = _uncalibratable(statistics)
        if reason is not None:
            _fallback(reason, postprocess)


def resolve_postprocessing(
    postprocess: str | list,
    statistics: SourceStatistics,
    *,
    clean: Any,
    labels: Any,
    grid: Grid,
    packing_region: dict[str, float] | None,
    pore_texture: np.ndarray | None = None,
    seed: int = 0,
    n_grains: int | None = None,
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
    packing_region : dict or None
        ``radius``, ``z_min``, ``z_max`` of the pour's bulk sub-cylinder, physical
        units (``PourChecks.packing_region``); ``calibrated`` measures there. None:
        the whole grid is bulk (an interior crop).
    pore_texture : ndarray of float64, shape (T, T, T), optional
        The render's pore texture density (`~synthpack.render.reconstruct.Background.texture_density`),
        for ``calibrated`` (`~synthpack.artefacts.calibrate`).
    seed : int
        What ``randomised`` draws the pack's image formation with (the pack's own seed,
        or one derived from it); unused by the other modes.
    n_grains : int, optional
        The grains poured: where ``calibrated`` falls back for want of a bulk region, its
        warning says about how many grains would give one.

    Returns
    -------
    Postprocessing

    Raises
    ------
    SynthpackInputError
        For a value that is neither one of `POSTPROCESS_MODES` nor a list.
    """
    _check_mode(postprocess)
    if isinstance(postprocess, list):
        return Postprocessing(from_config(postprocess), {"postprocess_mode": "custom"})
    if postprocess == "generic":
        return Postprocessing(generic_postprocessing(contrast=statistics.contrast), {"postprocess_mode": "generic"})
    if postprocess == "none":
        return Postprocessing(Compose([]), {"postprocess_mode": "none"})
    calibration, fallback = None, None
    if postprocess in ("calibrated", "randomised"):
        calibration, fallback = _fit(statistics, clean, labels, grid, packing_region, pore_texture, n_grains)
        if calibration is not None and postprocess == "calibrated":
            return Postprocessing(calibration.pipeline(),
                                  {"postprocess_mode": "calibrated", "calibration": calibration.to_dict()},
                                  band_map=calibration.band_mapping(),
                                  band_map_rounding=next(iter(calibration.rounding()), None))
        if fallback is not None:
            _fallback(fallback, postprocess)
    matched = None if calibration is not None else _matched_noise(statistics, clean, labels)
    if postprocess == "randomised":
        result = _randomised(statistics, calibration, matched, seed)
    else:
        result = Postprocessing(Compose([GaussianNoise(std=matched["noise_std"])]),
                                {"postprocess_mode": "match_source", "noise_match": matched})
    if fallback is not None:
        result.record["postprocess_fallback"] = fallback
    return result


def _fit(statistics: SourceStatistics, clean: Any, labels: Any, grid: Grid, packing_region: dict[str, float] | None,
         pore_texture: np.ndarray | None, n_grains: int | None) -> tuple[Calibration | None, str | None]:
    """``(calibration, None)``, or ``(None, why not)`` where the pack cannot be calibrated."""
    fallback = _uncalibratable(statistics)
    if fallback is not None:
        return None, fallback
    targets = _calibration_targets(statistics)
    try:
        in_height, in_disc = bulk_parts(grid.shape, grid.origin, grid.voxel_size, packing_region, n_grains)
    except SynthpackInputError as error:
        return None, str(error)  # "no bulk region: the pack is ... deep ...; pour about N grains ..."
    try:
        # only the slices the fit measures (and its halo) are made and read: the bulk of a big pack is
        # larger than memory; the fit is the same as on the whole bulk (`measured_slices`)
        start, stop = measured_slices(in_height, in_disc)
        halo = calibration_halo(targets["target_sigma"])
        low, high = max(0, start - halo), min(grid.shape[0], stop + halo)
        region = np.zeros((high - low, *grid.shape[1:]), dtype=bool)
        region[start - low:stop - low] = in_disc
        return calibrate(clean[low:high], labels[low:high], region, pore_texture=pore_texture, **targets), None
    except SynthpackInputError as error:
        return None, f"this pack: {error}"


def _matched_noise(statistics: SourceStatistics, clean: Any, labels: Any) -> dict[str, float]:
    """``match_source``'s record: the source's and the clean pack's noise level, and the std to add."""
    window = _central_slab(labels.shape)
    clean_noise = estimate_noise(clean[window], labels[window]).std
    noise = noise_to_add(statistics.noise_std, clean_noise)
    return {"target_noise": float(statistics.noise_std), "clean_noise": float(clean_noise),
            "noise_std": float(noise.std)}


def _draw_randomised(rng: np.random.Generator) -> dict[str, Any]:
    """One pack's draws from `RANDOMISED_RANGES` (all of them, always in this order)."""
    ranges = RANDOMISED_RANGES
    log_gamma = rng.uniform(*np.log(ranges["gamma"]))
    return {
        "blur_factor": float(rng.uniform(*ranges["blur_factor"])),
        "noise_factor": float(rng.uniform(*ranges["noise_factor"])),
        "white_noise": bool(rng.random() < ranges["white_noise"]),
        "cupping_offset": float(rng.uniform(*ranges["cupping_offset"])),
        "n_rings": int(rng.integers(ranges["n_rings"][0], ranges["n_rings"][1] + 1)),
        "ring_factor": float(rng.uniform(*ranges["ring_factor"])),
        "ring_width": float(rng.uniform(*ranges["ring_width"])),
        "contrast": float(rng.uniform(*ranges["contrast"])),
        "gamma": float(np.exp(log_gamma)),
    }


def _randomised(statistics: SourceStatistics, calibration: Calibration | None, matched: dict | None,
                seed: int) -> Postprocessing:
    """``randomised``: a pipeline drawn with `seed` about `calibration` (or, without it, `matched` noise)."""
    ranges = RANDOMISED_RANGES
    drawn = _draw_randomised(generator(seed, "recipe"))
    levels = {"pore_level": float(statistics.pore_mean), "grain_level": float(statistics.grain_mean)}
    rings = statistics.ring_amplitudes
    centre = {
        "blur_sigma": calibration.blur_sigma if calibration is not None else 0.0,
        "noise_std": calibration.noise_std if calibration is not None else matched["noise_std"],
        "cupping_strength": float(statistics.cupping_strength or 0.0),
        "ring_amplitude": max(max((abs(a) for a in rings), default=0.0) if rings else 0.0,
                              ranges["min_ring_amplitude"] * abs(statistics.contrast)),
    }
    factor = drawn["noise_factor"]
    white = drawn["white_noise"] or calibration is None
    if white:
        noise = GaussianNoise(std=factor * centre["noise_std"])
    else:
        added = calibration.added_phase_noise
        noise = ColouredNoise(
            pore_power=[factor**2 * v for v in calibration.added_power["pores"]],
            grain_power=[factor**2 * v for v in calibration.added_power["grains"]],
            pore_std=None if added["pores"] is None else factor * added["pores"],
            grain_std=None if added["grains"] is None else factor * added["grains"], **levels)
    pipeline = Compose([
        GaussianBlur(sigma=drawn["blur_factor"] * max(centre["blur_sigma"], ranges["min_blur"])),
        noise,
        BeamHardening(strength=float(np.clip(centre["cupping_strength"] + drawn["cupping_offset"], -0.9, 0.9)),
                      keep="mean"),
        RingArtefacts(amplitude=drawn["ring_factor"] * centre["ring_amplitude"], n_rings=drawn["n_rings"],
                      width=drawn["ring_width"]),
        ContrastGamma(contrast=drawn["contrast"], gamma=drawn["gamma"], **levels),
    ])
    record = {"seed": int(seed), "ranges": {k: list(v) if isinstance(v, tuple) else v for k, v in ranges.items()},
              "centre": centre, "drawn": {**drawn, "white_noise": white}, "pipeline": pipeline.to_config(),
              "calibration": calibration.to_dict() if calibration is not None else None,
              "noise_match": matched}
    return Postprocessing(pipeline, {"postprocess_mode": "randomised", "randomised": record})


def _central_slab(shape: tuple[int, ...], max_voxels: int = NOISE_SAMPLE_VOXELS) -> tuple[slice, ...]:
    """The central slices of a volume of `shape` holding at most about `max_voxels` voxels (at least one slice)."""
    n = min(shape[0], max(1, max_voxels // math.prod(shape[1:])))
    start = (shape[0] - n) // 2
    return (slice(start, start + n), slice(None), slice(None))


def bulk_region(
    shape: tuple[int, int, int],
    origin: tuple[float, float, float],
    voxel_size: tuple[float, float, float],
    packing_region: dict[str, float] | None,
    n_grains: int | None = None,
) -> np.ndarray:
    """Voxels of a pack grid inside the bulk sub-cylinder of its pour.

    The sub-cylinder is the one the pour's packing-fraction check uses
    (`synthpack.physics.checks`): one median grain diameter from the tube wall
    and floor, two below the top of the pack. Calibration fits there, and the
    realism report measures there. A pack that is an interior crop of its pour's
    bulk (``reconstruct.view: interior``, no wall, no air) is bulk throughout.

    Parameters
    ----------
    shape : tuple of 3 int
        ``(Z, Y, X)`` of the pack volumes.
    origin : tuple of 3 float
        World position ``(z, y, x)`` of the centre of voxel ``(0, 0, 0)``, physical units.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)``, physical units.
    packing_region : dict or None
        ``radius``, ``z_min``, ``z_max`` of the sub-cylinder about the world z axis,
        physical units (``PourChecks.packing_region``); None for an interior crop:
        every voxel.
    n_grains : int, optional
        The grains poured: the error for a pack without a bulk says about how many
        would give one (`~synthpack.physics.checks.bulk_shortfall`).

    Returns
    -------
    ndarray of bool, shape (Z, Y, X)
        True for voxels whose centre lies in the sub-cylinder.

    Raises
    ------
    SynthpackInputError
        If fewer than `MIN_REGION_VOXELS` voxels lie in it (a pack too shallow or too
        narrow to have a bulk): one line that says why and what gives one.
    """
    in_height, in_disc = bulk_parts(shape, origin, voxel_size, packing_region, n_grains)
    return in_height[:, None, None] & in_disc[None, :, :]


def bulk_parts(
    shape: tuple[int, int, int],
    origin: tuple[float, float, float],
    voxel_size: tuple[float, float, float],
    packing_region: dict[str, float] | None,
    n_grains: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`bulk_region` as its two factors, without the (Z, Y, X) mask: the slices (Z,) and the disc (Y, X), bool.

    Parameters and errors as `bulk_region`.
    """
    if packing_region is None:
        in_height, in_disc = np.ones(shape[0], dtype=bool), np.ones(shape[1:], dtype=bool)
    else:
        z = origin[0] + np.arange(shape[0]) * voxel_size[0]
        y = origin[1] + np.arange(shape[1]) * voxel_size[1]
        x = origin[2] + np.arange(shape[2]) * voxel_size[2]
        in_disc = np.hypot(y[:, None], x[None, :]) <= packing_region["radius"]
        in_height = (z >= packing_region["z_min"]) & (z <= packing_region["z_max"])
    voxels = int(np.count_nonzero(in_height)) * int(np.count_nonzero(in_disc))
    if voxels < MIN_REGION_VOXELS:
        why = (f"the pack has {voxels} voxels, fewer than {MIN_REGION_VOXELS}" if packing_region is None
               else bulk_shortfall(packing_region, n_grains))
        raise SynthpackInputError(f"no bulk region: {why}")
    return in_height, in_disc
