"""`SourceStatistics`: what synthpack measures of a source scan, once, before it builds anything from it."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any
from dataclasses import asdict, dataclass, field

import numpy as np

from .._shared.arrays import without_cupping
from .._shared.text import fraction, sig
from ..errors import SynthpackInputError
from ..scan.core import Scan
from ..measure.contacts import mean_coordination
from ..measure.edges import edge_profile, edge_width, interior_depth, signed_distance
from ..measure.grey_levels import grey_level_grid
from ..measure.noise_estimate import estimate_noise
from ..measure.phases import estimate_phases
from ..measure.psf import fit_edge_spread
from ..measure.patch_features import PatchReference
from ..measure.pore_histogram import measure_pore_quantiles
from ..measure.pore_spectrum import measure_pore_spectrum
from ..measure.scanner import measure_scanner
from ..measure.phase_histograms import band_quantiles, phase_masks, phase_quantiles
from ..measure.specimen import edge_coverage, is_interior_crop, solid_fraction, specimen_mask
from ..measure.semivariogram import phase_semivariograms
from ..measure.spectrum import measurable_phase_spectra, phase_interiors
from ..measure.volume_spectrum import TILES, cylindrical_spectrum
from ..measure.steepness import edge_steepness

logger = logging.getLogger(__name__)

__all__ = ["SourceStatistics", "measure_source"]


@dataclass(frozen=True)
class SourceStatistics:
    """Measured figures of a source scan that the later stages reproduce.

    Intensities are in the scan's own intensity units, lengths in voxels of the
    scan. The particle library stores them (`ParticleLibrary.statistics`; in
    ``library.json`` under ``phases``, one entry per field in this order, an
    optional field that was not measured left out).

    To add a statistic: add a field here, documented with its unit, and measure
    it in `measure_source` (a new field changes what a library holds on disk, so
    also raise the library's format version).

    Attributes
    ----------
    pore_mean : float
        Pore level: median intensity of the pore interior (voxels of label 0 at
        least `~synthpack.measure.phases.PORE_INTERIOR_DEPTH` voxels from a grain).
        The value outside each particle's mask in its clean crop, and the level of
        the space between grains in a pack.
    pore_std : float
        Pore spread: robust standard deviation (1.4826 x MAD) of the pore interior;
        the amplitude of the pack's pore texture.
    grain_mean : float
        Grain level: median intensity of the grain voxels. Above or below the
        pore level: grains are darker than the phase around them in neutron CT,
        with doped brine, or for aggregates in cement paste (see `contrast`).
    noise_std : float
        Noise level, pooled over grains and pores (`~synthpack.measure.noise_estimate.estimate_noise`).
    edge_width : float or None
        10-90 % rise distance (voxels) of the mean intensity profile across the
        grain-pore boundaries (`~synthpack.measure.edges.volume_edge_width`), the
        same for grains brighter or darker than pores; None when it cannot be
        measured (no grain or pore interior, or grains and pores of one level).
    edge_shift, edge_sigma : float or None
        The scanner's edge: half-height position relative to the label boundary
        (voxels, > 0 inside the grains) and Gaussian width (voxels) of the
        edge-spread function fitted to the same profile
        (`~synthpack.measure.psf.fit_edge_spread`); None with `edge_width`.
    noise_grain_std, noise_pore_std : float or None
        The noise level of each phase (`~synthpack.measure.noise_estimate.estimate_noise`), intensity
        units; None where the phase has too few interior voxels.
    nps_grains, nps_pores : tuple of float or None
        Noise power spectrum of the grain and of the pore interior, eroded by the edges'
        reach (`~synthpack.measure.edges.interior_depth` of `edge_sigma`), measured on the
        noise alone (`~synthpack.measure.spectrum.noise_power_spectrum`: second differences
        across slices): the power in rings ``k = 1, 2, ...`` at ``k / NPS_PATCH`` cycles
        per voxel, intensity units squared (their sum is the noise variance within an
        in-slice patch of `~synthpack.measure.spectrum.NPS_PATCH` voxels); None where the
        phase is too thin to measure.
    nps_depth : float or None
        Voxels from the edges beyond which `nps_grains` and `nps_pores` were measured, where
        both phases are too thin at the edges' reach (small grains and narrow pores): the
        deepest at which one of them holds enough voxel pairs
        (`~synthpack.measure.spectrum.measurable_phase_spectra`). None: at the edges' reach.
    pore_spectrum : tuple of float or None
        Power spectral density of the pore interior's intensity fluctuations on
        every scale up to `~synthpack.measure.pore_spectrum.PORE_SPECTRUM_SIZE`
        voxels (`~synthpack.measure.pore_spectrum.measure_pore_spectrum`), radially
        averaged over 3D shells ``k = 0, 1, ...`` at ``k / PORE_SPECTRUM_SIZE``
        cycles per voxel, intensity units squared times voxels cubed; the pack's
        pore texture is drawn from it. None where the pore interior is too small.
    pore_quantiles : tuple of float or None
        Shape of the pore interior's intensity histogram: quantiles of ``(I - median) / std``
        at the probabilities of `~synthpack.measure.pore_histogram.QUANTILE_SCORES`
        (`~synthpack.measure.pore_histogram.measure_pore_quantiles`), dimensionless; the
        measured pore texture's values are mapped onto it. None where the pore interior is too small.
    scan_axis : (float, float) or None
        ``(y, x)`` of the scan's rotation axis in every slice, voxels
        (`~synthpack.measure.scanner.rotation_axis`); None for an empty specimen.
    cupping_strength : float or None
        `~synthpack.artefacts.BeamHardening` strength of the scan's cupping (dimensionless,
        < 0 for a brighter centre), `~synthpack.measure.scanner.measure_scanner`; None where
        not significant.
    cupping_error : float or None
        Its standard error (also when not significant); None where not measured.
    ring_radii, ring_amplitudes : tuple of float or None
        Radius (voxels from the axis) and signed peak (intensity units) of each ring
        artefact found; None where none is.
    ring_width : float or None
        The rings' common full width at half maximum, voxels; None with `ring_radii`.
    wall_intensity, wall_thickness, wall_gap : float or None
        The container wall around the specimen: intensity (intensity units), thickness
        and gap between the specimen and its inner face (voxels); None where there is none.
    solid_fraction : float or None
        Bulk solid fraction: the fraction of the specimen's voxels
        (`~synthpack.measure.specimen.specimen_mask`) that are grain
        (`~synthpack.measure.specimen.solid_fraction`), dimensionless; the default
        target of a pour (``pour.target_solid_fraction: source``). None for a
        library of an older synthpack.
    histogram_grains, histogram_pores, histogram_edges : tuple of float or None
        The full-band intensity histogram of the specimen's grain interior, pore interior
        and edge voxels (`~synthpack.measure.phase_histograms.phase_masks`), as quantiles
        (`~synthpack.measure.phase_histograms.phase_quantiles`), intensity units: what the
        calibration's guard (`~synthpack.artefacts.guard`) measures a pack against. None
        where a phase has too few voxels.
    band_histograms : tuple of (tuple of float or None) or None
        The full-band intensity histogram of the specimen's voxels in each band of signed
        distance from the labels' boundary (`~synthpack.measure.phase_histograms.band_quantiles`,
        bands `~synthpack.measure.phase_histograms.BAND_KEYS`, in that order), as quantiles,
        intensity units; None for a band with too few voxels. ``postprocess: calibrated`` maps a
        pack's bands onto them where its phase histograms miss the source's
        (`~synthpack.artefacts.band_map`). None in a library of an older synthpack.
    coordination : float or None
        Mean coordination number: contacts per grain of the complete grains centred in
        the specimen (`~synthpack.measure.contacts.mean_coordination`, the count the
        realism report makes), dimensionless; the default target of a pour
        (``pour.target_coordination: source``). None where no complete grain is centred
        in the specimen.
    edge_coverage : float or None
        Fraction of the scan's four side faces that lie in its specimen
        (`~synthpack.measure.specimen.edge_coverage`), dimensionless; with no wall
        measured, it says whether the scan is an interior crop (`interior_crop`).
    semivariogram_grains, semivariogram_pores : tuple of float or None
        The fine texture of the grain and of the pore interior (eroded as for the noise
        spectra): the in-slice semivariogram at lags 1 to
        `~synthpack.measure.semivariogram.LAGS` voxels
        (`~synthpack.measure.semivariogram.semivariogram`), intensity units squared; what
        ``postprocess: calibrated`` fills a pack's texture to. None where a phase is too thin
        to measure, or in a library of an older synthpack.
    grey_levels : (float, float) or None
        ``(step, offset)``: the grid every value of the scan lies on
        (`~synthpack.measure.grey_levels.grey_level_grid`): ``(1, 0)`` for whole numbers (an
        integer file, 8 or 16 bit, as most scans are stored), or the regular steps of a float
        file of scaled integers; ``postprocess: calibrated`` puts a pack's intensities on the
        same grid (`~synthpack.artefacts.RoundLevels`). None where the values lie on no grid.
    air_intensity : float or None
        The air around the container (`~synthpack.measure.scanner.Wall.air`), intensity
        units: what a pack's tube has outside its wall. None where no wall was measured, or
        in a library of an older synthpack.
    edge_steepness : tuple of float or None
        How steep the scan's edges are, read without its labels: the upper tail of the
        absolute differences between in-slice neighbours in the specimen, at
        `~synthpack.measure.steepness.STEEPNESS_PROBABILITIES`
        (`~synthpack.measure.steepness.edge_steepness`), intensity units; ``postprocess:
        calibrated`` fits the pack's PSF to it. None in a specimen too small, or in a library of
        an older synthpack (the PSF is then fitted to the label-aligned edge alone).
    patch_window : (float, float) or None
        The intensity window of the scan's classifier patches (its 0.5 and 99.5 percentiles),
        intensity units (`~synthpack.measure.patch_features.PatchReference`).
    patch_features : tuple of (tuple of float) or None
        `~synthpack.measure.patch_features.patch_features` of up to
        `~synthpack.measure.patch_features.MAX_PATCHES` of the specimen's in-slice patches,
        windowed (dimensionless): what ``postprocess: calibrated``'s guard measures a pack's
        logistic AUC against (`~synthpack.artefacts.guard`).
    logistic_floor : float or None
        The logistic AUC of the specimen's even slabs against its odd ones (the realism
        report's floor), dimensionless. These three are None where too few patches fit in the
        specimen, or in a library of an older synthpack.
    volume_spectra : tuple of (tuple of (tuple of float)) or None
        The specimen's 3D power spectrum about the slice normal, structure and noise together
        (`~synthpack.measure.volume_spectrum.cylindrical_spectrum`: rows ``|f_z|``, columns the
        in-slice frequency), intensity units squared, 6 significant digits: one table for each cube
        side of `~synthpack.measure.volume_spectrum.TILES` of which enough cubes fit in the specimen,
        the largest first (32 voxels, then 16), so that a pack whose calibration region holds no
        cube of 32 (a narrow tube) is matched at 16. What ``postprocess: calibrated``'s spectrum
        match gives a pack (`~synthpack.artefacts.spectrum_match`). None where too few cubes of any
        side fit.
    """

    pore_mean: float
    pore_std: float
    grain_mean: float
    noise_std: float
    edge_width: float | None = None
    edge_shift: float | None = None
    edge_sigma: float | None = None
    noise_grain_std: float | None = None
    noise_pore_std: float | None = None
    nps_grains: tuple[float, ...] | None = None
    nps_pores: tuple[float, ...] | None = None
    nps_depth: float | None = None
    pore_spectrum: tuple[float, ...] | None = None
    pore_quantiles: tuple[float, ...] | None = None
    scan_axis: tuple[float, float] | None = None
    cupping_strength: float | None = None
    cupping_error: float | None = None
    ring_radii: tuple[float, ...] | None = None
    ring_amplitudes: tuple[float, ...] | None = None
    ring_width: float | None = None
    wall_intensity: float | None = None
    wall_thickness: float | None = None
    wall_gap: float | None = None
    solid_fraction: float | None = None
    histogram_grains: tuple[float, ...] | None = None
    histogram_pores: tuple[float, ...] | None = None
    histogram_edges: tuple[float, ...] | None = None
    coordination: float | None = None
    edge_coverage: float | None = None
    semivariogram_grains: tuple[float, ...] | None = None
    semivariogram_pores: tuple[float, ...] | None = None
    grey_levels: tuple[float, float] | None = None
    edge_steepness: tuple[float, ...] | None = None
    air_intensity: float | None = None
    band_histograms: tuple[tuple[float, ...] | None, ...] | None = None
    patch_window: tuple[float, float] | None = None
    patch_features: tuple[tuple[float, ...], ...] | None = field(default=None, repr=False)  # 600 x 41 numbers
    logistic_floor: float | None = None
    volume_spectra: tuple[tuple[tuple[float, ...], ...], ...] | None = field(default=None, repr=False)  # 17 x 24, 9 x 13

    @property
    def contrast(self) -> float:
        """Grain level minus pore level, intensity units: signed, negative for grains darker than pores.

        Amplitudes given as fractions of the contrast (noise, rings, histogram
        distances) use its magnitude; levels between the phases (the tube wall)
        use it signed.
        """
        return self.grain_mean - self.pore_mean

    @property
    def patch_reference(self) -> PatchReference | None:
        """The scan's patches for a logistic AUC against it (`patch_features`), or None where not measured."""
        if self.patch_features is None or self.patch_window is None or self.logistic_floor is None:
            return None
        return PatchReference(self.patch_window, np.asarray(self.patch_features, dtype=np.float64), self.logistic_floor)

    @property
    def interior_crop(self) -> bool:
        """Whether the scan is an interior crop: no wall, and grains to its side faces
        (`~synthpack.measure.specimen.is_interior_crop`); False where the coverage was not measured."""
        return self.edge_coverage is not None and is_interior_crop(self.edge_coverage, self.wall_intensity is not None)

    def summary(self) -> str:
        """One short line of the figures a person checks: phase levels, noise, edge blur, solid fraction, contacts.

        Intensities to 3 significant figures, lengths in voxels (``vx``); the scanner's
        figures (cupping, rings, wall) are `ScannerArtefacts.summary`'s; all of them are
        in the ``repr``.
        """
        edge = "edge not measured" if self.edge_sigma is None else f"edge sigma {sig(self.edge_sigma, 2)} vx"
        parts = [f"grains {sig(self.grain_mean)}", f"pores {sig(self.pore_mean)} ± {sig(self.pore_std)}",
                 f"noise {sig(self.noise_std)}", edge]
        if self.solid_fraction is not None:
            parts.append(f"solid {fraction(self.solid_fraction)}")
        if self.coordination is not None:
            parts.append(f"{sig(self.coordination, 2)} contacts/grain")
        return ", ".join(parts)

    def to_dict(self) -> dict[str, float | list]:
        """The measured fields as a JSON-able dict, in field order, without those that are None."""
        return {name: _lists(value) for name, value in asdict(self).items() if value is not None}

    @classmethod
    def from_dict(cls, data: Mapping[str, float | list[float]]) -> SourceStatistics:
        """Read back what `to_dict` wrote (a missing optional field is None; an older synthpack's ``whole_levels``
        is the grid of whole numbers where it was true)."""
        values = {name: _tuples(value) for name, value in data.items() if name != "whole_levels"}
        if data.get("whole_levels"):
            values.setdefault("grey_levels", (1.0, 0.0))
        return cls(**values)


def _lists(value: Any) -> Any:
    """`value` with its tuples, nested too, as lists (JSON)."""
    return [_lists(v) for v in value] if isinstance(value, tuple) else value


def _tuples(value: Any) -> Any:
    """`value` with its lists, nested too, as tuples (what `_lists` wrote)."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def measure_source(scan: Scan, exclude: tuple[int, int] | None = None, axis: int = 0) -> SourceStatistics:
    """Measure every `SourceStatistics` field of `scan`, inside its specimen.

    Parameters
    ----------
    scan : Scan
        Tomogram and labels (0 = pore, > 0 = grain).
    exclude : (start, stop), optional
        Slices ``start <= i < stop`` along `axis` that no figure may read (a held-out
        test block, `~synthpack.scan.split.central_block`): they are taken out of the
        specimen region every measure is restricted to, so the scan keeps its
        geometry (the rotation axis, the wall's radius) whatever the `axis`.
    axis : int
        Axis of `exclude` (0, 1 or 2).

    Returns
    -------
    SourceStatistics
        With the edge fields None (and a warning) when the scan's edges cannot be measured.

    Raises
    ------
    SynthpackInputError
        If the scan has no contrast (`~synthpack.measure.phases.PhaseLevels.check_contrast`), or
        the noise cannot be estimated (no grain or pore interior to measure it in).
    """
    whole = specimen_mask(scan.labels)
    specimen, readable = whole, None
    if exclude is not None:
        block = [slice(None)] * 3
        block[axis] = slice(*exclude)
        specimen, readable = whole.copy(), np.ones(whole.shape, dtype=bool)
        specimen[tuple(block)] = readable[tuple(block)] = False
    levels = estimate_phases(scan, region=specimen)
    levels.check_contrast()
    noise = estimate_noise(scan.tomogram, scan.labels, region=specimen)
    distance = signed_distance(scan.labels)
    edges: dict[str, float] = {}
    try:
        profile = edge_profile(scan.tomogram, distance, region=specimen)
        spread = fit_edge_spread(profile)
        edges = {"edge_width": edge_width(profile), "edge_shift": spread.shift, "edge_sigma": spread.sigma}
    except SynthpackInputError as error:
        logger.warning("the source's edge width cannot be measured (%s): packs of 'postprocess: calibrated' "
                       "(the default) will get noise matched to the source's level and no fitted blur", error)
    reach = interior_depth(edges.get("edge_sigma"))
    measured, nps_depth = measurable_phase_spectra(scan.tomogram, distance, specimen, reach)
    spectra: dict[str, Any] = {f"nps_{phase}": tuple(float(p) for p in spectrum.power[1:])
                               for phase, spectrum in measured.items() if spectrum is not None}
    if nps_depth != reach and spectra:
        spectra["nps_depth"] = nps_depth
        logger.info("noise spectrum measured %.2f voxels from the edges (no phase is wide enough %.2f from them)",
                    nps_depth, reach)
    spectra.update({f"histogram_{phase}": tuple(float(q) for q in quantiles)
                    for phase, quantiles in phase_quantiles(scan.tomogram, phase_masks(distance, specimen)).items()
                    if quantiles is not None})
    bands = band_quantiles(scan.tomogram, distance, specimen)
    if any(quantiles is not None for quantiles in bands.values()):
        spectra["band_histograms"] = tuple(None if q is None else tuple(float(v) for v in q) for q in bands.values())
    scanner = measure_scanner(scan.tomogram, scan.labels, whole, distance, pore_level=levels.pore_mean,
                              grain_level=levels.grain_mean, region=specimen)
    scanner_fields = scanner.statistics_fields() if scanner is not None else {}
    # The texture is rendered into the clean volume and the cupping is applied after it,
    # so the texture's figures are read with the cupping divided out (its radial trend is
    # not texture: counted in both, it would broaden the pack's pore histogram twice).
    flat = without_cupping(scan.tomogram, scanner_fields.get("cupping_strength"), scanner_fields.get("scan_axis"))
    pore_interior = phase_interiors(distance, specimen)["pores"]
    pore_spectrum = measure_pore_spectrum(flat, pore_interior)
    if pore_spectrum is None:
        logger.warning("the source's pore spectrum cannot be measured (too little pore interior): "
                       "packs get a Gaussian pore texture")
    else:
        spectra["pore_spectrum"] = tuple(float(p) for p in pore_spectrum)
    spectra.update({f"semivariogram_{phase}": tuple(float(g) for g in gamma)
                    for phase, gamma in phase_semivariograms(flat, distance, specimen, reach).items()
                    if gamma is not None})
    pore_quantiles = measure_pore_quantiles(flat, pore_interior)
    if pore_quantiles is not None:
        spectra["pore_quantiles"] = tuple(float(q) for q in pore_quantiles)
    steepness = edge_steepness(scan.tomogram, specimen)
    if steepness is not None:
        spectra["edge_steepness"] = tuple(float(q) for q in steepness)
    reference = PatchReference.measure(scan.tomogram, specimen)
    if reference is not None:
        # rounded: a record that reads the same on another CPU (a logistic fit differs in its last bits)
        spectra.update(patch_window=reference.window, logistic_floor=round(reference.floor, 3),
                       patch_features=tuple(tuple(round(float(v), 6) for v in row) for row in reference.features))
    tables = [t for t in (cylindrical_spectrum(scan.tomogram, specimen, tile=tile) for tile in TILES) if t is not None]
    if tables:  # 6 significant digits: a record that reads the same on another CPU
        spectra["volume_spectra"] = tuple(tuple(tuple(float(f"{v:.6g}") for v in row) for row in t) for t in tables)
    statistics = SourceStatistics(pore_mean=levels.pore_mean, pore_std=levels.pore_std,
                                  grain_mean=levels.grain_mean, noise_std=noise.std, **edges,
                                  noise_grain_std=noise.grain_std, noise_pore_std=noise.pore_std, **spectra,
                                  solid_fraction=solid_fraction(scan.labels, specimen),
                                  coordination=mean_coordination(scan.labels, specimen, readable=readable),
                                  edge_coverage=edge_coverage(whole), grey_levels=grey_level_grid(scan.tomogram),
                                  **scanner_fields)
    logger.info("source: %s", statistics.summary())
    logger.debug("source statistics of %s: %r", scan.source or "the scan", statistics)
    return statistics
