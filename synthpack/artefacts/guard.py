"""The calibration's guard: a step of the fitted post-processing stays only where it makes the pack more like its source.

`~synthpack.artefacts.calibrate` fits its steps (the PSF, the noise of each phase)
and adds the source's scanner artefacts; a fit can still go wrong on a scan it does
not suit. `guard_steps` applies the steps to the clean volume, on the region the
calibration measured (in the slices' window that gives every measured voxel the value
whole slices give it, so that the artefacts about the slice centre are where they will
be: `~synthpack.artefacts.calibrate`), and measures there, against the source's figures (`figures`):

* ``w_grains``, ``w_pores``, ``w_edges``: the Wasserstein distance of the phase's full-band
  intensity histogram from the source's (`~synthpack.measure.phase_histograms`), over the
  magnitude of the grain-pore contrast, as the realism report measures it;
* ``noise_grains``, ``noise_pores``: the relative error of the phase's noise level
  (`~synthpack.measure.noise_estimate.estimate_noise`), ``|noise / source's - 1|``.

Lower is more like the source. Every subset of the steps (kept in their order) is
measured. A subset is *admissible* when it leaves the pack no less like the source
than the clean volume (no post-processing) on any figure, to the figure's tolerance
(`TOLERANCE`), or, where a figure does get worse, still within its realism target
(`TARGET`: the issue-26 targets, a W of 5 % of the contrast, the noise level within
10 %): a blur that halves the edges' distance from the source's and leaves the grains'
within target is kept, one that moves a figure beyond its target and beyond no
post-processing's is not. The empty subset, the clean volume itself, is always
admissible, so calibration never makes a pack less like its source than no
post-processing on a figure it misses. The subset applied is an admissible one with the most steps (ties: the
lowest sum of the figures, then the first in the steps' order); then, one at a time, a
step whose leaving out makes some figure better and none worse (beyond the
tolerances) is left out too. A step left out is dropped: it made the pack less like
its source.

**The logistic AUC, recorded.** Where the source's classifier patches are known (``patches``,
`~synthpack.measure.patch_features.PatchReference`), the realism report's logistic AUC of the
region's in-slice patches against the source's is measured on the clean volume, with every
step, and as applied (`~synthpack.measure.patch_features.logistic_auc`), recorded
(``logistic``) and a warning given where the steps applied raise it beyond
`LOGISTIC_TOLERANCE`. It is not one of the figures the steps are chosen by: on the concrete
X-ray CT the only post-processings it prefers to none leave the paste without its noise or
the grains' noise 27 % or more off the scan's, packs that look less like the scan to the eye
and to every other figure.

**The band map.** Where, with the steps kept, a phase histogram (``w_grains``, ``w_pores``
or ``w_edges``) is still beyond its target and the source's histograms by distance from the
boundary are known (``bands``), a `~synthpack.artefacts.band_map.BandMap` is fitted on the
measured region after every subset of the steps, and the subset with its map that is
admissible and misses the fewest targets (ties: the most steps, then the lowest sum) is
applied instead, if it misses fewer targets than the steps kept without a map. A map
changes the noise level too (it stretches a band whose source histogram is wider), so each
subset that adds noise is tried again with each phase's noise scaled by what the map made of
its level (twice: the map is refitted on the rescaled volume), and a map may go with other
steps than those kept without it. The map of each side of the boundary is tried alone too
(the pores' shells, the grains' shells): stretching the grains' shells to a source whose
grains vary more from grain to grain also stretches the grains' noise, and a map of the
pores alone may then be the one that leaves no figure worse (a central 60x56x56 block of the
concrete neutron CT: every map of both sides left the grains' noise 36-160 % off the scan's,
so the guard kept no step at all and the paste no noise; the pores' map alone keeps them
all, the grains' noise within 2 %). A side alone is tried only where no map of both sides is
taken (so a pack that takes one costs what it did). It is asked for only where a
histogram misses: a pack whose histograms meet their targets keeps its bytes.

A step may need another (`guard_steps`'s ``requires``: a phase's texture is fitted with its
noise and replaces it), and subsets without it are not tried. Every drop is logged as a
warning. The guard is deterministic, and its cost fixed (at most 72 subsets: the blur,
cupping and rings each on or off, each phase's noise off, on or with its texture; each up to
three times more with a band map where one is tried, nine where a side alone is; of the calibration's at most
`~synthpack.artefacts.calibration_region.CALIBRATION_VOXELS` voxels): each step draws from its own fixed stream
(``calibration_guard``, keyed by the step's kind), so that the figures with and without
a step compare the same noise realisation.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from .._shared.seeds import generator
from .._shared.text import sig
from ..errors import SynthpackInputError
from ..measure.edges import INTERIOR, signed_distance
from ..measure.lattice import patch_corners
from ..measure.noise_estimate import estimate_noise, estimate_spread
from ..measure.patch_features import DEFAULT_PATCH, LOGISTIC_AUC_MARGIN, MAX_PATCHES, PatchReference
from ..measure.phase_histograms import phase_masks, phase_quantiles, quantile_distance
from ..measure.spectrum import NPS_RING_FACTOR, phase_spectra
from ..measure.volume_spectrum import MIN_CUBES, cube_corners, cylindrical_spectrum, table_tile
from ._base import Transform
from .band_map import BandMap, fit_band_map
from .spectrum_match import SpectrumMatch, fit_gain

logger = logging.getLogger(__name__)

__all__ = ["FIGURES", "LOGISTIC_TOLERANCE", "MAP_SIDES", "MEASURED_MARGIN", "SPECTRUM_MATCH_STRENGTHS", "TARGET",
           "TOLERANCE", "W_FIGURES", "figures", "guard_missed", "guard_spectrum_match", "guard_steps", "noise_ratios"]

#: The guard's figures, each lower = more like the source (see the module docstring).
FIGURES = ("w_grains", "w_pores", "w_edges", "noise_grains", "noise_pores")
#: The figures of the phase histograms: a band map is fitted where one of them misses its target.
W_FIGURES = FIGURES[:3]
#: How much a figure must change to count as better or worse: W as a fraction of the contrast, noise relative.
TOLERANCE = {"w_grains": 0.002, "w_pores": 0.002, "w_edges": 0.002, "noise_grains": 0.02, "noise_pores": 0.02}
#: The realism target of each figure (issue 26): a figure within it may get worse, to the benefit of others.
TARGET = {"w_grains": 0.05, "w_pores": 0.05, "w_edges": 0.05, "noise_grains": 0.1, "noise_pores": 0.1}
#: The kinds of transform a calibration holds, in pipeline order: each draws from its own key of the guard's stream.
_KINDS = ("gaussian_blur", "coloured_noise", "beam_hardening", "ring_artefacts")
#: Rounds of refitting the noise's amplitude after a band map (`guard_steps`'s ``rescaled``).
RESCALE_ROUNDS = 2
#: The range of that amplitude factor.
NOISE_SCALES = (0.25, 4.0)
#: How much the logistic AUC of the steps applied may exceed the clean volume's without a warning: about the spread
#: of its mean over the folds on a few hundred patches.
LOGISTIC_TOLERANCE = 0.01
#: The sides of the boundary a band map is tried on, each only where no map before it is taken (`_band_mapped`):
#: both, then the pores' bands alone, then the grains' alone (stretching one phase's shells can take its noise
#: beyond the source's where a map of the other phase alone leaves every figure no worse).
MAP_SIDES = (0, -1, 1)
#: The strengths of the spectrum match tried, the strongest first: the power gain raised to each (a filter that
#: takes a figure beyond its target at full strength may keep it within at half, and still bring the patches closer).
SPECTRUM_MATCH_STRENGTHS = (1.0, 0.5)
#: Voxels of the volume measured around the region: the noise estimate's filter and margin reach this far.
MEASURED_MARGIN = 3

Figures = dict[str, float]


def figures(
    volume: np.ndarray, masks: Mapping[str, np.ndarray], noise_labels: np.ndarray, *,
    histograms: Mapping[str, Sequence[float] | None], noise: Mapping[str, float | None], contrast: float,
) -> Figures:
    """The guard's figures of `volume` against the source's (see the module docstring).

    Parameters
    ----------
    volume : ndarray of float32, shape (Z, Y, X)
    masks : dict of str to ndarray of bool, same shape
        ``"grains"``, ``"pores"``, ``"edges"`` (`~synthpack.measure.phase_histograms.phase_masks`).
    noise_labels : ndarray of int, same shape
        The labels, -1 outside the measured region (`~synthpack.measure.noise_estimate.estimate_noise`).
    histograms : dict
        Per phase: the source's quantiles (`~synthpack.source.SourceStatistics.histogram_grains`), or None.
    noise : dict
        ``"grains"``, ``"pores"``: the source's noise level, intensity units, or None.
    contrast : float
        The source's grain-pore contrast, intensity units (signed; its magnitude is used).

    Returns
    -------
    dict of str to float
        The figures of `FIGURES` that can be measured (a phase without the source's figure,
        or too small in `volume`, has none).
    """
    result: Figures = {}
    for phase, quantiles in phase_quantiles(volume, masks).items():
        reference = histograms.get(phase)
        if quantiles is not None and reference is not None:
            result[f"w_{phase}"] = quantile_distance(quantiles, reference) / abs(contrast)
    result.update({f"noise_{phase}": abs(ratio - 1.0) for phase, ratio in noise_ratios(volume, noise_labels, noise).items()})
    return result


def noise_ratios(volume: np.ndarray, noise_labels: np.ndarray, noise: Mapping[str, float | None]) -> dict[str, float]:
    """Each phase's noise level in `volume` over the source's (`estimate_noise`; `figures`' noise figures are
    ``|ratio - 1|``), for the phases measured in both; empty where the noise cannot be estimated."""
    if not any(noise.values()):
        return {}
    try:
        estimate = estimate_noise(volume, noise_labels)
    except SynthpackInputError:
        return {}
    levels = {"grains": estimate.grain_std, "pores": estimate.pore_std}
    return {phase: levels[phase] / target for phase, target in noise.items()
            if phase in levels and target and levels[phase] is not None}


def _figures_and_ratios(volume: np.ndarray, masks: Mapping[str, np.ndarray], noise_labels: np.ndarray,
                        histograms: Mapping[str, Sequence[float] | None], noise: Mapping[str, float | None],
                        contrast: float) -> tuple[Figures, dict[str, float]]:
    """`figures` and `noise_ratios` of `volume`, the noise estimated once."""
    ratios = noise_ratios(volume, noise_labels, noise)
    without_noise = figures(volume, masks, noise_labels, histograms=histograms, noise={}, contrast=contrast)
    return {**without_noise, **{f"noise_{p}": abs(r - 1.0) for p, r in ratios.items()}}, ratios


def _rescaled_noise(scale: Mapping[str, float], ratios: Mapping[str, float]) -> dict[str, float] | None:
    """The noise amplitudes `scale`, each phase's divided by its level's ratio to the source's where that is off by
    more than its `TOLERANCE` (within `NOISE_SCALES`); None where no phase is."""
    off = {phase: r for phase, r in ratios.items() if abs(r - 1.0) > TOLERANCE[f"noise_{phase}"]}
    if not off:
        return None
    return {phase: float(np.clip(scale[phase] / off.get(phase, 1.0), *NOISE_SCALES)) for phase in scale}


def _excess(figures_: Figures, reference: Figures) -> dict[str, float]:
    """Per figure measured in both: how much `figures_` is above `reference`, less the tolerance (> 0: worse)."""
    return {name: figures_[name] - reference[name] - TOLERANCE[name] for name in FIGURES
            if name in figures_ and name in reference}


def _admissible(figures_: Figures, none: Figures) -> bool:
    """Whether no figure is worse than `none` (no post-processing) beyond its tolerance, unless within target."""
    return all(excess <= 0 or figures_[name] <= TARGET[name] for name, excess in _excess(figures_, none).items())


def _better(figures_: Figures, reference: Figures) -> bool:
    """Whether `figures_` is better than `reference` on some figure and worse on none, beyond the tolerances."""
    return (all(v <= 0 for v in _excess(figures_, reference).values())
            and any(v > 0 for v in _excess(reference, figures_).values()))


def _text(figures_: Figures) -> str:
    return ", ".join(f"{name} {sig(value, 2)}" for name, value in figures_.items())


def guard_steps(
    build: Callable[[tuple[str, ...]], list[Transform]],
    steps: Sequence[str],
    volume: np.ndarray,
    labels: np.ndarray,
    region: np.ndarray,
    *,
    histograms: Mapping[str, Sequence[float] | None],
    noise: Mapping[str, float | None],
    contrast: float,
    requires: Mapping[str, str] | None = None,
    bands: Mapping[int, Sequence[float] | None] | None = None,
    rescaled: Callable[[tuple[str, ...], Mapping[str, float]], list[Transform] | None] | None = None,
    patches: PatchReference | None = None,
) -> tuple[tuple[str, ...], dict]:
    """The steps to keep: the admissible subset most like the source (see the module docstring).

    Parameters
    ----------
    build : callable
        ``build(steps)``: the transforms that apply the named steps (a subset of `steps`), in order.
    steps : sequence of str
        The fitted steps, in order.
    volume : ndarray of float32, shape (Z, Y, X)
        The clean volume: whole slices, around `region` (with the blur's halo).
    labels : ndarray of int, same shape
        Its labels (0 = pore).
    region : ndarray of bool, same shape
        Where to measure.
    histograms, noise, contrast
        The source's figures, as `figures` takes them.
    requires : dict of str to str, optional
        A step that is only applied with another (a phase's texture with its noise): subsets
        with the first and not the second are not tried.
    bands : dict of int to sequence of float or None, optional
        The source's quantiles per band of distance (`~synthpack.source.SourceStatistics.band_histograms`):
        a band map is fitted where a phase histogram misses its target (module docstring); None: none.
    rescaled : callable, optional
        ``rescaled(steps, scale)``: as ``build(steps)`` with the noise each phase's steps add
        scaled in amplitude by ``scale[phase]`` (``"grains"``, ``"pores"``), or None where no step
        of `steps` adds noise: the noise is then refitted after a band map (module docstring).
        None: it is not.
    patches : PatchReference, optional
        The source's classifier patches: the logistic AUC is measured and recorded (module docstring);
        None: it is not.

    Returns
    -------
    kept : tuple of str
        The steps kept, in order.
    record : dict
        ``dropped`` (the steps left out), ``figures`` (``none``: the clean volume's,
        ``fitted``: with every step, ``applied``: with those kept, ``band_mapped``: with them and
        the band map, where one was fitted), ``band_map`` (the map kept, `BandMap.to_dict`, or
        None), ``band_map_status`` (``"applied"``, ``"dropped"``, ``"not needed"``: every phase
        histogram within target, ``"not measured"``: no source bands), ``noise_scale`` (the
        amplitude factor of each phase's noise applied with the map, or None), ``tolerance``,
        ``target``, ``voxels``, ``noise_voxels`` (the voxels each phase's noise level rests on,
        ``"grains"``, ``"pores"``; None where none), and with `patches` ``logistic`` (the AUC of ``none``, ``fitted``
        and ``applied``, the last with the band map where one is applied; None where too few
        patches fit in `region`).
    """
    box, distance, masks, noise_labels = _measured(labels, region)

    def applied(kept: tuple[str, ...], scale: Mapping[str, float] | None = None) -> np.ndarray:
        return _apply(build(kept) if scale is None else rescaled(kept, scale), volume)[box]

    def measure(out: np.ndarray) -> Figures:
        return figures(out, masks, noise_labels, histograms=histograms, noise=noise, contrast=contrast)

    def at(kept: tuple[str, ...]) -> Figures:
        return measure(applied(kept))

    steps, requires = tuple(steps), dict(requires or {})

    def valid(subset: tuple[str, ...]) -> bool:
        return all(requires[s] in subset for s in subset if s in requires)

    subsets = [subset for chosen in range(2 ** len(steps))
               if valid(subset := tuple(s for i, s in enumerate(steps) if chosen >> i & 1))]
    measured = {subset: at(subset) for subset in subsets}
    none, fitted = measured[()], measured[steps]
    admissible = [s for s in subsets if _admissible(measured[s], none)]
    kept = min(admissible, key=lambda s: (-len(s), sum(measured[s].values()), subsets.index(s)))
    while True:
        better = next((w for w in (tuple(k for k in kept if k != s) for s in kept)
                       if valid(w) and _better(measured[w], measured[kept])), None)
        if better is None:
            break
        kept = better
    band_map, status, mapped, scale = None, "not measured", None, None
    if bands and any(q is not None for q in bands.values()):
        status = "not needed"
        if _missed(measured[kept], W_FIGURES):
            def measure_with_ratios(out: np.ndarray) -> tuple[Figures, dict[str, float]]:
                return _figures_and_ratios(out, masks, noise_labels, histograms, noise, contrast)

            kept, band_map, mapped, scale = _band_mapped(subsets, measured, kept, applied, measure_with_ratios,
                                                         distance, region[box], bands, rescaled)
            status = "dropped" if band_map is None else "applied"
    dropped = [s for s in steps if s not in kept]
    for step in dropped:
        logger.warning("calibration: the %s step is dropped: it makes the pack less like its source "
                       "(with every step: %s; applied: %s; no post-processing: %s)", step, _text(fitted),
                       _text(mapped or measured[kept]), _text(none))
    record = {"dropped": dropped, "figures": {"none": none, "fitted": fitted, "applied": measured[kept]},
              "band_map": None if band_map is None else band_map.to_dict(), "band_map_status": status,
              "noise_scale": scale,
              "tolerance": dict(TOLERANCE), "target": dict(TARGET), "voxels": int(np.count_nonzero(region)),
              "noise_voxels": _noise_voxels(volume[box], noise_labels)}
    if mapped is not None:
        record["figures"]["band_mapped"] = mapped
    if patches is not None:
        packed = applied(kept, scale) if band_map is None else band_map.apply(applied(kept, scale), distance)
        record["logistic"] = _logistic(patches, region[box], {"none": applied(()), "fitted": applied(steps),
                                                              "applied": packed})
    logger.info("calibration guard: %s (no post-processing: %s)", _text(mapped or measured[kept]), _text(none))
    return kept, record


def _measured(labels: np.ndarray, region: np.ndarray) -> tuple[tuple[slice, ...], np.ndarray, dict, np.ndarray]:
    """What the guard measures of `region`: its box (with `MEASURED_MARGIN`), and there the signed distance
    from the labels' boundaries, the phase masks and the noise labels (-1 outside the region)."""
    where = np.argwhere(region)
    box = tuple(slice(max(0, int(lo) - MEASURED_MARGIN), int(hi) + 1 + MEASURED_MARGIN)
                for lo, hi in zip(where.min(axis=0), where.max(axis=0)))
    distance = signed_distance(labels[box])
    return (box, distance, phase_masks(distance, region[box]),
            np.where(region[box], np.asarray(labels[box], dtype=np.int64), -1))


def _apply(transforms: Sequence[Transform], volume: np.ndarray) -> np.ndarray:
    """`transforms` applied to `volume` in order, each from the guard's own stream of its kind."""
    out = volume
    for transform in transforms:
        kind = _KINDS.index(transform.name) if transform.name in _KINDS else len(_KINDS)
        out = transform(out, generator(0, "calibration_guard", kind))
    return out


def guard_spectrum_match(
    transforms: Sequence[Transform],
    volume: np.ndarray,
    labels: np.ndarray,
    region: np.ndarray,
    targets: Sequence[np.ndarray],
    *,
    histograms: Mapping[str, Sequence[float] | None],
    noise: Mapping[str, float | None],
    contrast: float,
    patches: PatchReference | None,
    ring_powers: Mapping[str, Sequence[float]] | None = None,
    nps_depth: float = INTERIOR,
    band_map: BandMap | None = None,
    rounding: Sequence[Transform] = (),
    strengths: Sequence[float] = SPECTRUM_MATCH_STRENGTHS,
    noise_scale: Mapping[str, float] | None = None,
    rescaled: Callable[[Mapping[str, float]], Sequence[Transform]] | None = None,
) -> dict:
    """Fit a `~synthpack.artefacts.spectrum_match.SpectrumMatch` after the steps kept, and keep it where it helps.

    The steps (`transforms`) are applied to `volume` as `guard_steps` applies them; the
    spectrum of the result in `region` (`~synthpack.measure.volume_spectrum.cylindrical_spectrum`)
    gives the gain towards the first of `targets` whose cubes fit in `region` often enough
    (`~synthpack.measure.volume_spectrum.MIN_CUBES`; a narrow tube's region holds cubes of 16
    voxels where it holds none of 32), `~synthpack.artefacts.spectrum_match.fit_gain`. Both
    volumes, without and with the filter, are then finished as the pack will be (the band map
    with the labels, then the rounding) and measured: the filter is applied only where the
    report's logistic AUC of the region's patches against the source's falls by at least the
    realism target's margin (`~synthpack.measure.patch_features.LOGISTIC_AUC_MARGIN`: a filter that
    reshapes every frequency is not worth less; on the concrete neutron CT it gained 0.020), no
    more of the guard's figures miss their targets, no phase's noise level moves further from the
    source's than its tolerance or than without the filter (the guard's slices read it less exactly
    than the whole pack: the sand scan's anisotropic variant passed at 6 % off and read 12 % on the
    whole pack), and each phase's worst ring of its noise
    spectrum (the realism report's figure) stays within the target's factor of the source's
    (`~synthpack.measure.spectrum.NPS_RING_FACTOR`), or no further from it than without the
    filter, which reshapes the noise too. Where the filter moves a phase's noise level by more
    than its tolerance (`TOLERANCE`, a fifth of the target) and the steps draw noise (`rescaled`),
    the steps are applied again with that phase's noise amplitude scaled to put it back
    (`RESCALE_ROUNDS` times, within `NOISE_SCALES`, as after a band map) and judged again; the
    last round that passes is taken. Where none passes at the whole gain, it is tried at the lower
    `strengths` (the power gain raised to each), and the first that passes is applied.

    Parameters
    ----------
    transforms : sequence of Transform
        The calibrated steps kept, in order.
    volume, labels, region
        As `guard_steps` takes them.
    targets : sequence of ndarray of float64, shape (T // 2 + 1, radii(T))
        The source's spectra (`~synthpack.source.SourceStatistics.volume_spectra`), of cubes of side ``T``,
        the largest side first: the pack's is read in cubes of the same side as the one matched.
    histograms, noise, contrast
        The source's figures, as `figures` takes them.
    patches : PatchReference or None
        The source's classifier patches; None: the filter is not judged, so not applied.
    ring_powers : dict, optional
        ``"grains"``, ``"pores"``: the source's noise power per ring (`~synthpack.measure.spectrum`),
        measured in the phases' interiors `nps_depth` voxels from the edges; None: rings not judged.
    band_map : BandMap, optional
        Applied after the steps, with the labels; after the filter, refitted to the filtered
        shells' histograms (`BandMap.refitted`: the filter reshapes each shell's histogram too).
    rounding : sequence of Transform
        Applied last.
    strengths : sequence of float
        The powers of the gain tried, in order (`SPECTRUM_MATCH_STRENGTHS`).
    noise_scale : dict of str to float, optional
        ``"grains"``, ``"pores"``: the noise amplitude factors `transforms` were made with; None: 1.
    rescaled : callable, optional
        ``rescaled(scale)``: the steps with the noise amplitudes `scale`; None: the noise is not rescaled.

    Returns
    -------
    dict
        ``status`` (``"applied"``, ``"dropped"``, or ``"not measured"``: too few cubes in the region
        or no patches to judge by), ``gain`` (the table at the strength applied or last tried,
        flattened row by row, or None) and ``level`` (the steps' mean intensity in the region, which
        the filter keeps), ``tile`` and ``cubes`` (the side and number of the region's cubes); where
        judged, ``strength`` (applied or last tried), ``noise_scale`` (the noise amplitudes with it,
        or None where not rescaled), ``tried`` (per strength: its noise scale, logistic AUC and the
        figures it misses), ``logistic`` and ``figures`` (``without``, ``with``) and ``band_map``
        (the map refitted after the filter, `BandMap.to_dict`, or None).
    """
    fits = {table_tile(t): len(cube_corners(region, table_tile(t))) for t in targets}  # cubes per side
    target = next((t for t in targets if fits[table_tile(t)] >= MIN_CUBES), targets[-1])
    tile = table_tile(target)
    cubes = fits[tile]
    out = _apply(transforms, volume)
    pack = cylindrical_spectrum(out, region, tile=tile)
    record: dict = {"status": "not measured", "gain": None, "tile": tile, "cubes": cubes}
    if pack is None or patches is None:
        logger.debug("calibration: no spectrum match (%s)", "no classifier patches of the source to judge it by"
                     if pack is not None else f"{cubes} cubes of {tile} voxels in the region, fewer than needed")
        return record
    gain = np.round(fit_gain(np.asarray(target, dtype=np.float64), pack), 6)
    box, distance, masks, noise_labels = _measured(labels, region)

    def finished(result: np.ndarray, mapping: BandMap | None) -> np.ndarray:
        result = result[box] if mapping is None else mapping.apply(result[box], distance)
        return _apply(rounding, result)

    def worst_rings(result: np.ndarray) -> dict[str, float]:
        """Per phase measured, its worst ring's power factor from the source's, >= 1 either way (finite: a ring
        without power reads 1e12): the realism report's NPS figure."""
        spectra = phase_spectra(result, distance, region[box], nps_depth)
        return {phase: max((max(power / source, source / power) for power, source in zip(
                    np.maximum(spectra[phase].power[1:], 1e-12 * np.asarray(sources)), sources) if source > 0),
                           default=1.0)
                for phase, sources in sorted((ring_powers or {}).items()) if spectra.get(phase) is not None}

    level = round(float(np.mean(out[region], dtype=np.float64)), 6)
    corners = patch_corners(region[box], DEFAULT_PATCH, DEFAULT_PATCH // 2, MAX_PATCHES)

    def judged(volume: np.ndarray, mapping: BandMap | None) -> tuple[Figures, dict, dict, float | None]:
        """The figures of `volume` finished with `mapping`, its worst rings and noise ratios per phase, its AUC."""
        finished_ = finished(volume, mapping)
        rings = worst_rings(finished_)
        measured, ratios = _figures_and_ratios(finished_, masks, noise_labels, histograms, noise, contrast)
        measured["nps_worst_ring"] = float(max(rings.values(), default=1.0))
        return measured, rings, ratios, patches.auc(finished_, corners)

    without, rings, _, auc = judged(out, band_map)
    tried = []
    for strength in strengths:
        gain_ = np.round(gain**strength, 6)
        match = SpectrumMatch(gain=gain_.ravel().tolist(), level=level)
        steps, scale, rounds = out, dict(noise_scale or {"grains": 1.0, "pores": 1.0}), []
        for round_ in range(RESCALE_ROUNDS + 1):
            matched = match(steps, 0)
            # the band map fitted without the filter, refitted to the filtered shells' histograms
            refitted = None if band_map is None else band_map.refitted(matched[box], distance, region[box])
            measured, rings_, ratios, auc_ = judged(matched, refitted or band_map)
            helps = (None not in (auc, auc_) and auc_ <= auc - LOGISTIC_AUC_MARGIN
                     and _missed(measured) <= _missed(without)
                     and all(measured[name] <= max(without.get(name, 0.0), TOLERANCE[name])
                             for name in ("noise_grains", "noise_pores") if name in measured)
                     and all(w <= max(rings.get(phase, 1.0), NPS_RING_FACTOR) for phase, w in rings_.items()))
            rounds.append({"helps": helps, "noise_scale": None if steps is out else scale, "measured": measured,
                           "logistic": auc_, "band_map": refitted})
            # the filter moved a phase's noise level: its noise drawn at the amplitude that puts it back (a level
            # within its target but off by more than the tolerance too: the pack's whole bulk reads it less exactly)
            scale_ = _rescaled_noise(scale, ratios)
            if rescaled is None or scale_ is None or round_ == RESCALE_ROUNDS:
                break
            scale, steps = scale_, _apply(rescaled(scale_), volume)
        chosen = next((r for r in reversed(rounds) if r["helps"]), rounds[-1])  # the most rescaled that helps
        tried.append({"strength": strength, "noise_scale": chosen["noise_scale"], "logistic": chosen["logistic"],
                      "missed": _missed(chosen["measured"])})
        if chosen["helps"]:
            break
    measured, auc_, refitted = chosen["measured"], chosen["logistic"], chosen["band_map"]
    record.update(status="applied" if chosen["helps"] else "dropped", gain=gain_.ravel().tolist(), level=level,
                  strength=strength, noise_scale=chosen["noise_scale"], tried=tried,
                  logistic={"without": auc, "with": auc_}, figures={"without": without, "with": measured},
                  band_map=None if refitted is None else refitted.to_dict())
    logger.info("calibration: spectrum match %s at strength %s (logistic AUC on %d cubes' region %s without, %s with; "
                "%s)", record["status"], strength, cubes, *(sig(a, 3) if a is not None else "n/a" for a in (auc, auc_)),
                _text(measured))
    return record


def _noise_voxels(volume: np.ndarray, noise_labels: np.ndarray) -> dict[str, int] | None:
    """The voxels each phase's noise level rests on in the guard's region (`estimate_noise`), or None where it has
    none; said (INFO) where so few that the level's spread between noise draws (`estimate_spread`) reaches its
    target."""
    try:
        estimate = estimate_noise(volume, noise_labels)
    except SynthpackInputError:
        return None
    counts = {"grains": estimate.n_grain, "pores": estimate.n_pore}
    for phase, count in counts.items():
        if count and estimate_spread(count) >= TARGET[f"noise_{phase}"]:
            logger.info("calibration guard: the %s' noise level rests on %d voxels of its region, where it varies "
                        "by %.0f %% between noise draws, as much as its %.0f %% target: its figure is that uncertain",
                        phase, count, 100 * estimate_spread(count), 100 * TARGET[f"noise_{phase}"])
    return counts


def _logistic(patches: PatchReference, region: np.ndarray, volumes: Mapping[str, np.ndarray]) -> dict:
    """The logistic AUC of each of `volumes`' patches in `region` against the source's; a warning where the
    ``applied`` one is above the ``none`` one beyond `LOGISTIC_TOLERANCE`."""
    corners = patch_corners(region, DEFAULT_PATCH, DEFAULT_PATCH // 2, MAX_PATCHES)
    auc = {name: patches.auc(volume, corners) for name, volume in volumes.items()}
    if auc["applied"] is not None and auc["none"] is not None and auc["applied"] > auc["none"] + LOGISTIC_TOLERANCE:
        logger.warning("calibration: the pack's patches look less like the source's with the steps applied than "
                       "without them to the realism report's logistic regression (AUC %.3f against %.3f on the "
                       "calibration's slices), though its histograms and noise levels are closer: compare the packs "
                       "with `synthpack compare` (or use `postprocess: none`)", auc["applied"], auc["none"])
    return auc


def guard_missed(record: Mapping) -> int:
    """How many targets a guarded pack misses (`guard_steps`'s `record`): its applied figures' (with the band map,
    where one was fitted)."""
    return _missed(record["figures"].get("band_mapped") or record["figures"]["applied"])


def _missed(figures_: Figures, names: Sequence[str] = FIGURES) -> int:
    """How many of the figures `names` measured in `figures_` are beyond their target."""
    return sum(figures_[name] > TARGET[name] for name in names if name in figures_)


def _band_mapped(
    subsets: list[tuple[str, ...]], measured: dict[tuple[str, ...], Figures], kept: tuple[str, ...],
    applied: Callable[..., np.ndarray], measure: Callable[[np.ndarray], tuple[Figures, dict[str, float]]],
    distance: np.ndarray, region: np.ndarray,
    bands: Mapping[int, Sequence[float] | None], rescaled: Callable | None,
) -> tuple[tuple[str, ...], BandMap | None, Figures | None, dict[str, float] | None]:
    """The steps, band map and noise scale to apply, with their figures; `kept`, None, None, None where no band map
    makes the pack more alike.

    A band map is fitted on every subset of the steps, and, where the subset adds noise
    (`rescaled` says so), again with each phase's noise scaled by what the map made of it
    (``scale / (level / source's level)``, `RESCALE_ROUNDS` times, within `NOISE_SCALES`); all
    of it with the map of both sides of the boundary, then of the pores' shells alone, then of
    the grains' alone (`MAP_SIDES`), each only where none before it is taken. Of those fitted, the
    one that is admissible (no figure worse than no post-processing beyond its tolerance, unless
    within target) and misses the fewest targets (ties: the most steps, both sides, the lowest
    sum of the figures, unscaled first) is taken if it misses fewer than `kept` does without one.
    """
    none = measured[()]
    fits: list[tuple[tuple[str, ...], dict[str, float] | None, BandMap, Figures, int]] = []

    def fit(subset: tuple[str, ...], scale: dict[str, float] | None, side: int) -> dict[str, float] | None:
        volume = applied(subset, scale)
        band_map = fit_band_map(volume, distance, region, bands)
        if band_map is not None and side:
            band_map = band_map.side(side)
        if band_map is None:
            return None
        mapped, ratios = measure(band_map.apply(volume, distance))
        fits.append((subset, scale, band_map, mapped, side))
        return ratios

    for side in MAP_SIDES:  # one side alone only where no map of both sides is taken: a fixed cost otherwise
        for subset in subsets:
            levels = fit(subset, None, side)
            scale = {"grains": 1.0, "pores": 1.0}
            if levels is None or rescaled is None or rescaled(subset, scale) is None:
                continue
            for _ in range(RESCALE_ROUNDS):
                scale = _rescaled_noise(scale, levels)
                if scale is None:
                    break
                levels = fit(subset, scale, side)
        admissible = [f for f in fits if _admissible(f[3], none)]
        if not admissible:
            continue
        subset, scale, band_map, mapped, _ = min(admissible, key=lambda f: (
            _missed(f[3]), -len(f[0]), f[4] != 0, sum(f[3].values()), f[1] is not None, subsets.index(f[0])))
        if _missed(mapped) < _missed(measured[kept]):
            logger.info("calibration: band map fitted (%d bands) with the steps %s%s: %s", len(band_map.bands),
                        ", ".join(subset) or "none", "" if scale is None else
                        ", the noise scaled by " + ", ".join(f"{sig(v, 3)} in the {p}" for p, v in scale.items()),
                        _text(mapped))
            return subset, band_map, mapped, scale
    logger.warning("calibration: no band map is applied: none brings the pack's histograms closer to its source's "
                   "without moving another figure away (without one: %s)", _text(measured[kept]))
    return kept, None, None, None

