"""Post-processing fitted to a source scan: blur and noise that match its image formation, never making it less alike.

The clean synthetic volume is rendered with partial-volume edges (`synthpack.render.partial_volume`) from grain
crops that hold the source's noise thinned by resampling, between pores that hold the pore texture. `calibrate`
fits the rest of the scanner's image formation to the source (`~synthpack.source.SourceStatistics`), inside a
region of the pack (its bulk). A representative sample is enough: the fit measures the central slices of the
region holding at most `~synthpack.artefacts.calibration_region.CALIBRATION_VOXELS` of its voxels
(`~synthpack.artefacts.calibration_region.central_slices`; in a region too wide, a central square of them), so
its cost is fixed and vanishes per voxel on big packs.

1. **Point-spread function.** The width of the clean volume's edge-spread function
   is fitted (`~synthpack.measure.psf.fit_edge_spread`, on the mean edge profile
   of `synthpack.measure.edges`), and the Gaussian PSF that brings it to the
   source's ``edge_sigma`` found by `PSF_STEPS` fixed-point steps on the law
   that Gaussian widths add in quadrature, ``sigma_psf^2 <- sigma_psf^2 +
   target^2 - fitted(sigma_psf)^2`` from ``sigma_psf = 0`` (each step blurs with
   `~synthpack.artefacts.GaussianBlur` and fits again; none if the clean volume
   is already as blurred): the source's PSF less what the render's partial volume
   and interpolation already blur. The edge's position (the render's occupancy
   shift) is not changed by a symmetric blur.

   That profile is read across the *labels*, and a real scan's labels (a watershed's)
   scatter about its true boundaries, which broadens the source's profile as a wider
   PSF would. So the width is then fitted to what the labels do not touch, the
   steepness of the edges (`~synthpack.measure.steepness`: the upper tail of the
   in-slice neighbour differences, `~synthpack.source.SourceStatistics.edge_steepness`):
   the scatter only widens the profile, so its width is an upper bound, and of the
   widths `STEEPNESS_FACTORS` (0.5 to 1) times it the one is kept whose blurred clean
   volume, with the noise of step 2 fitted at the profile's width, has the tail nearest
   the source's; the noise is then fitted again at that width. Without the source's
   steepness (a library of an older synthpack) the profile's width stays.
2. **Noise.** The noise power spectrum of the grain and pore interiors of the
   blurred volume, eroded by the PSF's reach (`~synthpack.measure.edges.interior_depth`
   of the source's edge width), is measured on the noise alone
   (`~synthpack.measure.spectrum.noise_power_spectrum`: the second difference across
   slices, in which structure that varies smoothly over three slices cancels: the pore
   texture and the grains' own texture are not counted as noise), as the source's was
   (`~synthpack.source.SourceStatistics.nps_grains`), and
   `~synthpack.artefacts.ColouredNoise` adds, ring by ring and phase by phase, the
   power the source has beyond it (the deficit; none where the pack already has
   as much): the noise the crops and the pore texture carry is accounted for. In a
   phase too thin to measure (too few voxel pairs at a patch's lags) the clean spectrum is
   that of white noise at the phase's clean noise level, plus, in the pores, the
   expected spectrum of the render's pore texture after the blur (computed from
   its density, `~synthpack.render.pore_texture.PoreTextureConfig.density`). The
   same is done for the noise level `~synthpack.measure.noise_estimate.estimate_noise`
   measures (3D second differences; variances add), which pins the noise's 3D high
   frequencies that the in-slice spectrum says little of.

   **Texture.** What the noise spectra cannot see, the fine texture of the source's grain
   and pore interiors (`~synthpack.measure.semivariogram`: the in-slice semivariogram at
   lags of 1 to 4 voxels, in the same eroded interiors), is fitted with the noise: one
   spectrum, the noise's knots plus a Gaussian-correlated texture (a variance and a
   correlation length), fitted to the ring powers, the noise level and the semivariogram
   the pack lacks at once (`~synthpack.artefacts.coloured_noise.fit_noise_and_texture`),
   so that neither takes the other's share. The phase's `~synthpack.artefacts.ColouredNoise`
   carries both. Without the source's semivariogram (a library of an older synthpack) or
   where a phase is too thin to measure it in the pack, the noise alone, as before.

3. **Scanner artefacts**, where the source shows them
   (`~synthpack.measure.scanner.measure_scanner`), applied last with the source's
   measured values, fixed: `~synthpack.artefacts.BeamHardening` of the source's
   cupping strength (relative to the field of view, which for a pack's tube sized
   from the source's lateral extent is about the source's), keeping the mean level
   (``keep="mean"``: the pack's phase levels are the source's medians, which hold
   its cupping averaged over the field already) and
   `~synthpack.artefacts.RingArtefacts` at the source's ring radii, amplitudes and
   width, both about the slice centre, which is the pack's tube axis. Each is a
   per-slice radial table, so it costs one pass over the volume. Off where the source
   shows none (None in its statistics).

4. **The guard** (`~synthpack.artefacts.guard`): every subset of the steps (the blur, the
   noise of each phase, the cupping, the rings) is applied to the clean volume on the
   measured slices (in the window of them `~synthpack.artefacts.calibration_region.lateral_window` keeps: the values of whole slices
   on what is measured, at the cost of the region), and the full-band histograms of grains,
   pores and edges (Wasserstein distance over the contrast, against the source's
   `~synthpack.source.SourceStatistics.histogram_grains` and the others) and the noise
   levels are measured. The steps applied are the largest subset that leaves no figure
   worse than the clean volume's (beyond a small tolerance) unless that figure stays within
   its realism target; a step whose removal makes some figure better and none worse is
   dropped too: calibration never makes a pack less like its source than no
   post-processing on a figure it misses. Each drop is a warning and is recorded
   (`Calibration.guard`). Where the guard drops the blur, the PSF is fitted again at
   `NARROWER_PSF` of its width and guarded, and kept where the pack then misses fewer
   targets. Where the source's classifier patches are known
   (`~synthpack.source.SourceStatistics.patch_reference`), the realism report's logistic AUC
   of the region's patches against them is recorded, without and with the steps, and a
   warning given where the steps raise it.

5. **The band map**, where the guard still finds a phase histogram beyond its target and the
   source's histograms by distance from the boundary are known
   (`~synthpack.source.SourceStatistics.band_histograms`): a monotone map of each band of
   signed distance onto the source's, fitted after the steps kept and kept only where it
   brings the histograms closer (`~synthpack.artefacts.band_map`, `Calibration.band_map`).
   It reads the pack's labels, so it is applied after the pipeline
   (`~synthpack.artefacts.band_map.apply_band_map`).

6. **The grey-level grid.** Where the source's values lie on a grid (an 8 or 16 bit file, or
   floats of regular steps: `~synthpack.source.SourceStatistics.grey_levels`),
   `~synthpack.artefacts.RoundLevels` rounds the pack's intensities to it last (after the band map, where there is one), so that its neighbour differences come in the
   source's steps. Not a guarded step, but the guard measures every subset rounded, as the pack
   will be, and the noise is fitted less the white noise the rounding adds
   (`~synthpack.artefacts.intensity.rounding_variance`, ``step^2/12``): the source's noise holds its
   own rounding, and a pack whose noise matched it before rounding read 7 % noisier after it
   (the sand micro-CT).

7. **The spectrum match**, where the source's 3D power spectrum is known (`~synthpack.source.SourceStatistics.volume_spectra`):
   a linear filter fitted on the steps' output (`~synthpack.artefacts.spectrum_match`) gives the pack the source's
   spectrum about the slice normal, structure and noise together, applied after the steps (before the band map,
   refitted after it, and the rounding) only where it lowers the logistic AUC of the region's patches against the
   source's and misses no more targets (`~synthpack.artefacts.guard.guard_spectrum_match`, `Calibration.spectrum_match`).

The fit has no random part (the guard draws from its own fixed stream); with the pack's
seed the noise realisation is reproducible too. It records the grid search and every
value it matched or applied.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from .._shared.seeds import generator
from .._shared.text import sig
from ..errors import SynthpackInputError
from ..measure.edges import EdgeProfile, edge_profile, edge_width, interior_depth, signed_distance
from ..measure.noise_estimate import estimate_noise
from ..measure.patch_features import PatchReference
from ..measure.psf import EdgeSpread, fit_edge_spread
from ..measure.semivariogram import phase_semivariograms
from ..measure.spectrum import NoiseSpectrum, phase_spectra, white_ring_powers
from ..measure.steepness import edge_steepness, steepness_distance
from ._base import Compose, Transform
from .band_map import BandMap
from .blur import GaussianBlur
from .coloured_noise import ColouredNoise, fit_noise_and_texture, ring_powers_of_spectrum
from .intensity import RoundLevels, rounding_variance
from .calibration_region import CALIBRATION_VOXELS, bounding_box, calibration_halo, central_slices, lateral_window
from .guard import guard_missed, guard_spectrum_match, guard_steps
from .noise import GaussianNoise
from .radial import BeamHardening, RingArtefacts
from .spectrum_match import SpectrumMatch

logger = logging.getLogger(__name__)

__all__ = ["Calibration", "NARROWER_PSF", "PSF_STEPS", "STEEPNESS_FACTORS", "STEPS", "calibrate", "noise_to_add"]

#: Fixed-point steps of the PSF fit (the fitted width is within about 0.01 voxel after 3).
PSF_STEPS = 3
#: The PSF widths the steepness fit tries, as multiples of the edge profile's fixed point: at most 1, as the
#: labels' scatter only ever widens the profile.
STEEPNESS_FACTORS = tuple(round(0.5 + 0.05 * k, 2) for k in range(11))
#: Where the guard drops the fitted blur, the PSF is fitted again at these fractions of its width and guarded,
#: and kept where its guarded pack misses fewer targets (`~synthpack.artefacts.guard.guard_missed`): a
#: narrower blur can bring a pack closer to its source where the fitted one moves a figure away.
NARROWER_PSF = (0.5,)
#: The steps of a calibration, in the order they apply (`Calibration.transforms`).
STEPS = ("blur", "grain_noise", "grain_texture", "pore_noise", "pore_texture", "cupping", "rings")
#: A step that is only applied with another: a phase's texture replaces its noise by the noise fitted with it.
REQUIRES = {"grain_texture": "grain_noise", "pore_texture": "pore_noise"}


def noise_to_add(source: float, clean: float) -> GaussianNoise:
    """Gaussian noise of std ``sqrt(max(source^2 - clean^2, 0))``: variances add.

    Parameters
    ----------
    source, clean : float
        Noise standard deviations (as `~synthpack.measure.noise_estimate.estimate_noise`
        measures them) of the real scan and of the clean synthetic volume, in
        intensity units.

    Returns
    -------
    GaussianNoise
        With a fixed `std` (0 when the clean volume is already as noisy).
    """
    std = math.sqrt(max(source * source - clean * clean, 0.0))
    if source <= clean:
        logger.warning("the clean volume (noise %.4g) is already at least as noisy as the source (%.4g): "
                       "no noise added", clean, source)
    logger.info("matched noise: std %s added (source %s, clean pack %s)", sig(std), sig(source), sig(clean))
    return GaussianNoise(std=std)


@dataclass
class Calibration:
    """The fitted post-processing and what it matched.

    Attributes
    ----------
    blur_sigma : float
        Gaussian PSF applied to the clean volume, voxels.
    target_sigma, target_shift : float
        The source's fitted edge width and shift, voxels (`SourceStatistics.edge_sigma`, ``edge_shift``).
    edge_sigma, edge_shift : float
        The same fitted on the clean volume blurred by `blur_sigma`, voxels.
    pore_level, grain_level : float
        The source's phase levels, intensity units (the noise's phase fractions).
    target_power, clean_power, added_power : dict of str to list of float
        Per phase (``"grains"``, ``"pores"``): the source's noise power per ring, the
        blurred clean volume's, and the noise added (their clipped difference),
        intensity units squared; rings ``k = 1, 2, ...`` at ``k / NPS_PATCH`` cycles per voxel.
    target_phase_noise, clean_phase_noise, added_phase_noise : dict of str to float or None
        The same for the noise level (`~synthpack.measure.noise_estimate.estimate_noise`), intensity
        units (``added = sqrt(max(target^2 - clean^2, 0))``); None where not measured.
    target_edge_width, edge_width : float
        The source's 10-90 edge width and that of the blurred clean volume, voxels (a check).
    target_noise, noise_std : float
        The source's pooled noise level and the root mean square of `added_phase_noise`,
        intensity units (the figures the realism report prints).
    sigmas, fitted_sigmas : list of float
        The search: edge width fitted on the clean volume blurred by each sigma tried, voxels.
    steepness_sigmas, steepness_distances : list of float or None
        The steepness fit: each PSF width tried (voxels) and how far the blurred, noisy clean
        volume's edge steepness then was from the source's
        (`~synthpack.measure.steepness.steepness_distance`, dimensionless); `blur_sigma`
        is the nearest. None: not fitted (no source steepness, or no blur).
    cupping_strength : float or None
        The source's cupping, applied as `~synthpack.artefacts.BeamHardening`'s strength
        (dimensionless), keeping the mean level; None: none applied.
    ring_radii, ring_amplitudes : list of float or None
        The source's rings, applied by `~synthpack.artefacts.RingArtefacts`: radii from
        the tube axis (voxels) and signed peaks (intensity units); None: none applied.
    ring_width : float or None
        Their full width at half maximum, voxels.
    guard : dict or None
        What the guard (`~synthpack.artefacts.guard.guard_steps`) found: ``dropped``, the
        steps of `STEPS` left out of the pipeline because they made the pack less like its
        source (their fitted values are kept above), and the ``figures`` it measured; None:
        not guarded.
    target_semivariogram, clean_semivariogram : dict of str to list of float or None
        Per phase, the source's texture (`~synthpack.measure.semivariogram`, lags 1, 2, ...
        voxels, intensity units squared) and the blurred clean volume's; None where not measured.
    textured : dict of str to dict or None
        Per phase, the noise fitted together with the texture (the ``*_texture`` steps,
        `~synthpack.artefacts.coloured_noise.fit_noise_and_texture`): its ring powers
        ``power`` and level ``noise`` (as `added_power`, `added_phase_noise`) and the
        ``texture`` ``[variance, sigma]`` (intensity units squared, voxels; None where the
        noise's own knots carry it) that `~synthpack.artefacts.ColouredNoise` adds with it;
        None: no semivariogram to fit (not measured in the source or the pack).
    grey_levels : list of float or None
        ``[step, offset]``: the source's grey-level grid, which the pack's intensities end on
        (`~synthpack.artefacts.RoundLevels`, last in `pipeline`, or, with a `band_map`, after the
        map: `rounding`); None: not rounded.
    band_map : dict or None
        The `~synthpack.artefacts.band_map.BandMap` kept by the guard (`BandMap.to_dict`; refitted after
        the spectrum match where it is applied), applied after the pipeline with the pack's labels
        (`band_mapping`); None: none.
    noise_scale : dict of str to float or None
        ``"grains"``, ``"pores"``: the amplitude factor of each phase's fitted noise (and texture) that the
        guard applies with the band map or the spectrum match, which stretch or filter the noise too
        (`~synthpack.artefacts.guard`); None: 1.
    spectrum_match : dict or None
        What `~synthpack.artefacts.guard.guard_spectrum_match` fitted and found (``status``,
        ``gain``, ...): applied in `pipeline` where ``status`` is ``"applied"``; None: not fitted
        (no source spectrum).
    """

    blur_sigma: float
    target_sigma: float
    target_shift: float
    edge_sigma: float
    edge_shift: float
    pore_level: float
    grain_level: float
    target_power: dict[str, list[float]]
    clean_power: dict[str, list[float]]
    added_power: dict[str, list[float]]
    target_phase_noise: dict[str, float | None]
    clean_phase_noise: dict[str, float | None]
    added_phase_noise: dict[str, float | None]
    target_edge_width: float
    edge_width: float
    target_noise: float
    noise_std: float
    sigmas: list[float]
    fitted_sigmas: list[float]
    steepness_sigmas: list[float] | None = None
    steepness_distances: list[float] | None = None
    cupping_strength: float | None = None
    ring_radii: list[float] | None = None
    ring_amplitudes: list[float] | None = None
    ring_width: float | None = None
    guard: dict | None = None
    target_semivariogram: dict[str, list[float] | None] | None = None
    clean_semivariogram: dict[str, list[float] | None] | None = None
    textured: dict[str, dict | None] | None = None
    grey_levels: list[float] | None = None
    band_map: dict | None = None
    noise_scale: dict[str, float] | None = None
    spectrum_match: dict | None = None

    def fitted_steps(self) -> tuple[str, ...]:
        """The steps of `STEPS` that do something: a blur wider than 0, noise added to a phase, the source's artefacts."""
        adds = {phase: any(self.added_power[phase]) or bool(self.added_phase_noise[phase])
                for phase in ("grains", "pores")}
        textured = {phase: (self.textured or {}).get(phase) is not None for phase in ("grains", "pores")}
        does = {"blur": self.blur_sigma > 0, "grain_noise": adds["grains"] or textured["grains"],
                "grain_texture": textured["grains"], "pore_noise": adds["pores"] or textured["pores"],
                "pore_texture": textured["pores"], "cupping": self.cupping_strength is not None,
                "rings": self.ring_radii is not None}
        return tuple(step for step in STEPS if does[step])

    def applied_steps(self) -> tuple[str, ...]:
        """`fitted_steps` less those the guard dropped."""
        dropped = () if self.guard is None else self.guard["dropped"]
        return tuple(step for step in self.fitted_steps() if step not in dropped)

    def transforms(self, steps: Sequence[str], noise_scale: Mapping[str, float] | None = None) -> list[Transform]:
        """The transforms of `steps` (names of `STEPS`), in pipeline order.

        `GaussianBlur` (``blur``), one `ColouredNoise` holding the noise of the phases named
        (``grain_noise``, ``pore_noise``; none in a phase not named; with ``grain_texture`` or
        ``pore_texture`` too, the noise fitted with the texture and the texture), `BeamHardening`
        (``cupping``) and `RingArtefacts` (``rings``). `noise_scale` (``"grains"``, ``"pores"``)
        multiplies each phase's noise and texture amplitude (default 1).
        """
        transforms: list[Transform] = []
        if "blur" in steps:
            transforms.append(GaussianBlur(sigma=self.blur_sigma))
        noisy = {phase: f"{phase[:-1]}_noise" in steps for phase in ("grains", "pores")}
        if any(noisy.values()):
            fit = {phase: ((self.textured or {}).get(phase) if f"{phase[:-1]}_texture" in steps else None) or
                   {"power": self.added_power[phase], "noise": self.added_phase_noise[phase], "texture": None}
                   for phase in noisy}
            gain = {phase: (noise_scale or {}).get(phase, 1.0) for phase in noisy}
            power = {phase: [gain[phase] ** 2 * v for v in fit[phase]["power"]] if noisy[phase]
                     else [0.0] * len(self.added_power[phase]) for phase in noisy}
            std = {phase: None if not noisy[phase] or fit[phase]["noise"] is None else gain[phase] * fit[phase]["noise"]
                   for phase in noisy}
            texture = {phase: None if not noisy[phase] or fit[phase]["texture"] is None else
                       [gain[phase] ** 2 * fit[phase]["texture"][0], fit[phase]["texture"][1]] for phase in noisy}
            transforms.append(ColouredNoise(pore_power=power["pores"], grain_power=power["grains"],
                                            pore_level=self.pore_level, grain_level=self.grain_level,
                                            pore_std=std["pores"], grain_std=std["grains"],
                                            pore_texture=texture["pores"], grain_texture=texture["grains"]))
        if "cupping" in steps:
            transforms.append(BeamHardening(strength=self.cupping_strength, keep="mean"))
        if "rings" in steps:
            transforms.append(RingArtefacts(amplitude=max(abs(a) for a in self.ring_amplitudes),
                                            n_rings=len(self.ring_radii), width=self.ring_width,
                                            radii=self.ring_radii, amplitudes=self.ring_amplitudes))
        return transforms

    def pipeline(self) -> Compose:
        """The transforms of `applied_steps`: blur, coloured noise, the scanner's artefacts, the spectrum match, then
        the grey-level grid (unless a `band_map` follows, which rounds)."""
        return Compose(self.transforms(self.applied_steps(), self.noise_scale) + self.matched_spectrum()
                       + (self.rounding() if self.band_map is None else []))

    def matched_spectrum(self) -> list[SpectrumMatch]:
        """The `~synthpack.artefacts.SpectrumMatch` of `spectrum_match` where the guard applied it, else none."""
        match = self.spectrum_match or {}
        return [SpectrumMatch(gain=match["gain"], level=match["level"])] if match.get("status") == "applied" else []

    def rounding(self) -> list[RoundLevels]:
        """The last transform, onto the source's grey-level grid (`grey_levels`); none where it has none."""
        return [] if self.grey_levels is None else [RoundLevels(*self.grey_levels)]

    def band_mapping(self) -> BandMap | None:
        """The `band_map`, or None."""
        return None if self.band_map is None else BandMap.from_dict(self.band_map)

    def to_dict(self) -> dict:
        """JSON-able dict of every field."""
        return asdict(self)


def _clean_ring_powers(
    spectrum: NoiseSpectrum | None, n_rings: int, noise_std: float | None, texture: np.ndarray | None,
) -> np.ndarray:
    """Rings 1 to `n_rings` of the clean phase's spectrum: measured, or where no patch fits, modelled.

    The model: white noise of `noise_std` (0 if None), plus the expected ring powers of
    `texture` (a density on a periodic cube's FFT grid, already blurred; None: none).
    """
    if spectrum is not None:
        return spectrum.power[1 : n_rings + 1]
    powers = white_ring_powers((noise_std or 0.0) ** 2, n_rings)
    return powers if texture is None else powers + ring_powers_of_spectrum(texture, n_rings)


def _blurred(density: np.ndarray, sigma: float) -> np.ndarray:
    """A density on a cube's FFT grid after a Gaussian blur of `sigma` voxels: times ``exp(-4 pi^2 sigma^2 |f|^2)``."""
    f = np.fft.fftfreq(density.shape[0])
    gain = np.exp(-4.0 * np.pi**2 * sigma**2 * f**2)
    return density * gain[:, None, None] * gain[None, :, None] * gain[None, None, :]


def calibrate(
    clean: np.ndarray,
    labels: np.ndarray,
    region: np.ndarray,
    *,
    target_sigma: float,
    target_shift: float,
    target_power: dict[str, Sequence[float]],
    target_nps_depth: float | None = None,
    target_phase_noise: dict[str, float | None],
    target_edge_width: float,
    target_noise: float,
    pore_level: float,
    grain_level: float,
    pore_texture: np.ndarray | None = None,
    cupping_strength: float | None = None,
    rings: tuple[Sequence[float], Sequence[float], float] | None = None,
    target_histograms: dict[str, Sequence[float] | None] | None = None,
    target_semivariogram: dict[str, Sequence[float] | None] | None = None,
    target_steepness: Sequence[float] | None = None,
    target_bands: dict[int, Sequence[float] | None] | None = None,
    target_patches: PatchReference | None = None,
    target_spectra: Sequence[Sequence[Sequence[float]]] | None = None,
    grey_levels: Sequence[float] | None = None,
    steps: int = PSF_STEPS,
    max_voxels: int = CALIBRATION_VOXELS,
) -> Calibration:
    """Fit the PSF and the noise so the pack's edges and noise spectrum match the source's.

    Parameters
    ----------
    clean : ndarray of float32, shape (Z, Y, X)
        The synthetic volume before post-processing (or an array-like that
        slicing reads, e.g. a Zarr array: only `region`'s box is read).
    labels : ndarray of int, shape (Z, Y, X)
        Its labels (0 = pore, tube or outside).
    region : ndarray of bool, shape (Z, Y, X)
        Where to measure (the pack's bulk region, `~synthpack.artefacts.recipes.bulk_region`): its central
        slices holding at most `max_voxels` voxels (`~synthpack.artefacts.calibration_region.central_slices`).
    target_sigma, target_shift : float
        The source's fitted edge width and shift, voxels (`~synthpack.source.SourceStatistics.edge_sigma`).
    target_power : dict
        ``"grains"`` and ``"pores"``: the source's noise power per ring (rings 1, 2, ...),
        intensity units squared (`~synthpack.source.SourceStatistics.nps_grains`).
    target_nps_depth : float, optional
        Voxels from the edges beyond which the source's noise spectra were measured, and the
        pack's are (`~synthpack.source.SourceStatistics.nps_depth`); None: at the edges' reach.
    target_phase_noise : dict
        ``"grains"`` and ``"pores"``: the source's noise level, intensity units
        (`~synthpack.source.SourceStatistics.noise_grain_std`), or None (not matched).
    target_edge_width, target_noise : float
        The source's 10-90 edge width (voxels) and pooled noise level (intensity units),
        recorded next to the pack's for the report.
    pore_level, grain_level : float
        The source's phase levels, intensity units.
    pore_texture : ndarray of float64, shape (T, T, T), optional
        Power spectral density of the render's pore texture on the FFT grid of its
        tile (`~synthpack.render.pore_texture.PoreTextureConfig.density`): the clean pores'
        spectrum where no patch fits in the pack's pore interior.
    cupping_strength : float, optional
        The source's cupping (`~synthpack.source.SourceStatistics.cupping_strength`),
        applied last; None: none.
    rings : (radii, amplitudes, width), optional
        The source's rings (`~synthpack.source.SourceStatistics.ring_radii`,
        ``ring_amplitudes``, ``ring_width``; voxels, intensity units, voxels), applied
        last; None: none.
    target_histograms : dict, optional
        ``"grains"``, ``"pores"``, ``"edges"``: the source's full-band histograms as quantiles
        (`~synthpack.source.SourceStatistics.histogram_grains`), or None, which the guard
        measures the pack against (with the noise levels); None: the guard judges the
        noise levels only.
    target_semivariogram : dict, optional
        ``"grains"`` and ``"pores"``: the source's texture (`~synthpack.source.SourceStatistics.semivariogram_grains`),
        or None; None: no texture is fitted.
    target_steepness : sequence of float, optional
        The source's edge steepness (`~synthpack.source.SourceStatistics.edge_steepness`,
        intensity units): the PSF width is fitted to it (step 1); None: to the edge profile alone.
    target_bands : dict of int to sequence of float or None, optional
        The source's histograms by band of distance from the boundary
        (`~synthpack.source.SourceStatistics.band_histograms`, keyed by band): what a band map is
        fitted to (step 5); None: none is.
    target_patches : PatchReference, optional
        The source's classifier patches (`~synthpack.source.SourceStatistics.patch_reference`): the
        guard records the logistic AUC against them (step 4); None: it does not.
    target_spectra : sequence of (sequence of sequence of float), optional
        The source's spectra about the slice normal, per cube side (`~synthpack.source.SourceStatistics.volume_spectra`):
        a spectrum match is fitted to one of them (step 7); None: none is.
    grey_levels : (float, float), optional
        ``(step, offset)``: end the pipeline with `~synthpack.artefacts.RoundLevels` onto the
        source's grey-level grid (`~synthpack.source.SourceStatistics.grey_levels`); None: no rounding.
    steps : int
        Fixed-point steps of the PSF fit (see the module docstring).
    max_voxels : int
        Bound on the region's voxels measured (default
        `~synthpack.artefacts.calibration_region.CALIBRATION_VOXELS`).

    Returns
    -------
    Calibration
        Its `Calibration.guard` holds what the guard measured and dropped (step 4 of the module docstring).
    """
    if not (math.isfinite(target_sigma) and target_sigma > 0 and math.isfinite(target_shift)):
        raise SynthpackInputError(
            f"calibration targets must be a positive edge width and a finite shift, got {target_sigma!r} and "
            f"{target_shift!r}"
        )
    region = central_slices(region, max_voxels)
    box = bounding_box(region, calibration_halo(target_sigma))
    volume, box_labels, box_region = clean[box], np.asarray(labels[box]), region[box]
    distance = signed_distance(box_labels)

    def edge(sigma: float) -> tuple[np.ndarray, EdgeProfile, EdgeSpread]:
        blurred = GaussianBlur(sigma=float(sigma))(volume, 0)
        profile = edge_profile(blurred, distance, box_region)
        return blurred, profile, fit_edge_spread(profile)

    sigmas, fitted = [0.0], []
    blurred, profile, spread = edge(0.0)
    for _ in range(steps):
        fitted.append(spread.sigma)
        sigmas.append(math.sqrt(max(sigmas[-1] ** 2 + target_sigma**2 - spread.sigma**2, 0.0)))
        blurred, profile, spread = edge(sigmas[-1])
    fitted.append(spread.sigma)
    sigma = sigmas[-1]
    if sigma == 0.0:
        logger.warning("the clean pack's edges (width %.3f voxels) are already as soft as the source's (%.3f): "
                       "no blur", fitted[0], target_sigma)
    targets = {phase: np.asarray(power, dtype=np.float64) for phase, power in target_power.items()}
    nps_depth = interior_depth(target_sigma) if target_nps_depth is None else target_nps_depth
    # the last step's white noise, part of the source's
    rounding = 0.0 if grey_levels is None else rounding_variance(grey_levels[0])
    gamma_targets = {phase: None if target_semivariogram is None or target_semivariogram.get(phase) is None
                     else np.asarray(target_semivariogram[phase], dtype=np.float64) for phase in targets}

    def fit_at(sigma: float, blurred: np.ndarray, profile: EdgeProfile, spread: EdgeSpread) -> Calibration:
        """The calibration with a PSF of `sigma` (`blurred`, `profile`, `spread`: its edge) and the noise fitted to it."""
        measured = phase_spectra(blurred, distance, box_region, nps_depth)
        noise = estimate_noise(blurred, np.where(box_region, box_labels.astype(np.int64), -1))
        clean_noise = {"grains": noise.grain_std, "pores": noise.pore_std}
        textures = {"grains": None, "pores": None if pore_texture is None else _blurred(pore_texture, sigma)}
        cleans = {phase: _clean_ring_powers(measured[phase], len(targets[phase]), clean_noise[phase], textures[phase])
                  for phase in targets}
        gamma_cleans = (phase_semivariograms(blurred, distance, box_region, interior_depth(target_sigma))
                        if any(v is not None for v in gamma_targets.values()) else {phase: None for phase in targets})
        added, added_noise, textured = {}, {}, {}
        for phase in targets:
            target_level, clean_level = target_phase_noise.get(phase), clean_noise[phase]
            level = (None if target_level is None or clean_level is None
                     else target_level**2 - clean_level**2 - rounding)
            deficit = targets[phase] - cleans[phase] - white_ring_powers(rounding, len(targets[phase]))
            powers, highpass, _ = fit_noise_and_texture(deficit, level, None)
            added[phase] = np.asarray(powers)
            added_noise[phase] = None if highpass is None else math.sqrt(highpass)
            textured[phase] = None
            if gamma_targets[phase] is not None and gamma_cleans[phase] is not None:
                powers, highpass, texture = fit_noise_and_texture(deficit, level,
                                                                  gamma_targets[phase] - gamma_cleans[phase] - rounding,
                                                                  gamma_targets[phase])
                textured[phase] = {"power": list(powers), "noise": None if highpass is None else math.sqrt(highpass),
                                   "texture": texture}
        added_levels = [v for v in added_noise.values() if v is not None]
        return Calibration(
            blur_sigma=sigma, target_sigma=float(target_sigma), target_shift=float(target_shift),
            edge_sigma=spread.sigma, edge_shift=spread.shift, pore_level=float(pore_level),
            grain_level=float(grain_level), target_power={k: v.tolist() for k, v in targets.items()},
            clean_power={k: v.tolist() for k, v in cleans.items()},
            added_power={k: v.tolist() for k, v in added.items()},
            target_phase_noise=dict(target_phase_noise), clean_phase_noise=clean_noise, added_phase_noise=added_noise,
            target_edge_width=float(target_edge_width), edge_width=edge_width(profile), target_noise=float(target_noise),
            noise_std=math.sqrt(sum(v * v for v in added_levels) / len(added_levels)) if added_levels else 0.0,
            sigmas=sigmas, fitted_sigmas=fitted,
            cupping_strength=None if cupping_strength is None else float(cupping_strength),
            ring_radii=None if rings is None else [float(r) for r in rings[0]],
            ring_amplitudes=None if rings is None else [float(a) for a in rings[1]],
            ring_width=None if rings is None else float(rings[2]),
            target_semivariogram={k: None if v is None else v.tolist() for k, v in gamma_targets.items()},
            clean_semivariogram={k: None if v is None else v.tolist() for k, v in gamma_cleans.items()},
            textured=textured, grey_levels=None if grey_levels is None else [float(v) for v in grey_levels],
        )

    calibration = fit_at(sigma, blurred, profile, spread)
    if target_steepness is not None and sigma > 0.0:
        # the noise the pack gets (fitted at the profile's width) on each width tried
        noise = calibration.transforms(tuple(step for step in calibration.fitted_steps()
                                             if step.endswith(("_noise", "_texture"))))
        tried = [sigma * factor for factor in STEEPNESS_FACTORS]
        distances = _steepness_distances(volume, box_region, tried, noise,
                                         np.asarray(target_steepness, dtype=np.float64), grain_level - pore_level)
        if distances is not None:
            best = tried[int(np.argmin(distances))]
            if best != sigma:
                logger.info("PSF sigma %s vx from the edge profile, %s vx from the edges' steepness", sig(sigma, 3),
                            sig(best, 3))
                sigma = best
                calibration = fit_at(sigma, *edge(sigma))
            calibration.steepness_sigmas, calibration.steepness_distances = tried, distances
    def guarded(calibration: Calibration) -> Calibration:
        calibration.guard = _guard(calibration, clean, labels, region, target_histograms or {},
                                   calibration_halo(target_sigma), target_bands, target_patches)
        return calibration

    calibration = guarded(calibration)
    if "blur" in calibration.guard["dropped"]:
        tried = [{"sigma": sigma, "missed": guard_missed(calibration.guard)}]
        for factor in NARROWER_PSF:
            narrower = guarded(fit_at(sigma * factor, *edge(sigma * factor)))
            narrower.steepness_sigmas, narrower.steepness_distances = calibration.steepness_sigmas, calibration.steepness_distances
            tried.append({"sigma": sigma * factor, "missed": guard_missed(narrower.guard)})
            if guard_missed(narrower.guard) < guard_missed(calibration.guard):
                logger.info("the guard drops a PSF of %s vx; one of %s vx brings the pack closer to its source",
                            sig(sigma, 3), sig(sigma * factor, 3))
                calibration, sigma = narrower, sigma * factor
        calibration.guard["psf_tried"] = tried
    calibration.band_map = calibration.guard.pop("band_map")
    calibration.noise_scale = calibration.guard.pop("noise_scale")
    if target_spectra is not None:
        _match_spectrum(calibration, clean, labels, region, target_spectra, target_histograms or {},
                        calibration_halo(target_sigma), target_patches, nps_depth)
    noise_text = ", ".join(f"{phase} {sig(std)}" for phase, std in calibration.added_phase_noise.items()
                           if std is not None)
    noise_text += "".join(f", {phase} with texture" + ("" if t["texture"] is None else
                                                       f" {sig(math.sqrt(t['texture'][0]))} over {sig(t['texture'][1], 2)} vx")
                          for phase, t in calibration.textured.items()
                          if t is not None and f"{phase[:-1]}_texture" in calibration.applied_steps())
    dropped = calibration.guard["dropped"]
    logger.info("calibrated: PSF sigma %s vx (edges %s vx, source %s), noise added: %s%s%s%s%s",
                sig(sigma, 2), sig(calibration.edge_sigma, 2), sig(target_sigma, 2), noise_text or "none",
                "" if cupping_strength is None else f", cupping {sig(cupping_strength, 2)}",
                "" if rings is None else f", {len(rings[0])} ring(s)",
                f"; dropped by the guard: {', '.join(dropped)}" if dropped else "",
                "" if calibration.band_map is None else f"; band map of {len(calibration.band_map['bands'])} bands")
    logger.debug("%r", calibration)
    return calibration


def _steepness_distances(volume: np.ndarray, region: np.ndarray, sigmas: Sequence[float],
                         noise: Sequence[Transform], target: np.ndarray, contrast: float) -> list[float] | None:
    """For each PSF width of `sigmas`, the distance of the blurred, noisy `volume`'s edge steepness from `target`.

    The `noise` transforms (the calibration's noise steps) draw the same realisation at every
    width (stream ``calibration_fit``), so that the widths compare like with like. The tail is
    read in `region` (`~synthpack.measure.steepness.edge_steepness`); None where the region holds
    too few voxel pairs for it (a warning: the profile's width is kept).
    """
    distances = []
    for sigma in sigmas:
        out = GaussianBlur(sigma=float(sigma))(volume, 0)
        for index, transform in enumerate(noise):
            out = transform(out, generator(0, "calibration_fit", index))
        tail = edge_steepness(out, region)
        if tail is None:
            logger.warning("the pack's calibration region holds too few voxel pairs to read its edges' steepness: "
                           "the PSF is fitted to the edge profile alone")
            return None
        distances.append(steepness_distance(tail, target, contrast))
    return distances


def _guard(calibration: Calibration, clean: np.ndarray, labels: np.ndarray, region: np.ndarray,
           histograms: dict[str, Sequence[float] | None], halo: int,
           bands: dict[int, Sequence[float] | None] | None, patches: PatchReference | None) -> dict:
    """`~synthpack.artefacts.guard.guard_steps` of the calibration's fitted steps on the measured `region`.

    The slices of `clean` the region occupies (and `halo` more on each side, for the blur) are
    read, in each the window `~synthpack.artefacts.calibration_region.lateral_window` keeps: the artefacts about the slice centre lie
    where the pack's will, and every value the guard measures is the one whole slices give.
    """
    window = _guard_window(calibration, region, halo)
    rounds = calibration.rounding()  # measured as the pack will be: rounded last
    _, record = guard_steps(
        lambda steps: calibration.transforms(steps) + rounds, calibration.fitted_steps(),
        np.asarray(clean[window], dtype=np.float32), np.asarray(labels[window]), region[window], histograms=histograms,
        noise=calibration.target_phase_noise, contrast=calibration.grain_level - calibration.pore_level,
        requires=REQUIRES, bands=bands, patches=patches,
        rescaled=lambda steps, scale: calibration.transforms(steps, scale) + rounds
        if any(step.endswith(("_noise", "_texture")) for step in steps) else None)
    return record


def _guard_window(calibration: Calibration, region: np.ndarray, halo: int) -> tuple[slice, ...]:
    """The slices `region` occupies, `halo` more on each side, in the lateral window the guard reads."""
    occupied = np.flatnonzero(region.any(axis=(1, 2)))
    low, high = max(0, int(occupied[0]) - halo), min(region.shape[0], int(occupied[-1]) + 1 + halo)
    return (slice(low, high), *lateral_window(region, halo, "cupping" in calibration.fitted_steps()))


def _match_spectrum(calibration: Calibration, clean: np.ndarray, labels: np.ndarray, region: np.ndarray,
                    targets: Sequence[Sequence[Sequence[float]]], histograms: dict[str, Sequence[float] | None], halo: int,
                    patches: PatchReference | None, nps_depth: float) -> None:
    """Set `calibration`'s ``spectrum_match`` (`~synthpack.artefacts.guard.guard_spectrum_match` after the steps kept,
    on the guard's window) and, where the filter is applied, its ``band_map`` and ``noise_scale`` to those refitted."""
    window, steps = _guard_window(calibration, region, halo), calibration.applied_steps()
    record = guard_spectrum_match(
        calibration.transforms(steps, calibration.noise_scale),
        np.asarray(clean[window], dtype=np.float32), np.asarray(labels[window]), region[window],
        [np.asarray(t, dtype=np.float64) for t in targets], histograms=histograms, noise=calibration.target_phase_noise,
        contrast=calibration.grain_level - calibration.pore_level, patches=patches,
        ring_powers=calibration.target_power, nps_depth=nps_depth, band_map=calibration.band_mapping(),
        rounding=calibration.rounding(), noise_scale=calibration.noise_scale,
        rescaled=(lambda scale: calibration.transforms(steps, scale)) if any(
            step.endswith(("_noise", "_texture")) for step in steps) else None)
    band_map, noise_scale = record.pop("band_map", None), record.pop("noise_scale", None)
    if record["status"] == "applied":
        calibration.band_map = band_map or calibration.band_map
        calibration.noise_scale = noise_scale or calibration.noise_scale
    calibration.spectrum_match = record
