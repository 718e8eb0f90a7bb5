"""The scan's reconstruction artefacts: cupping (beam hardening), rings and the container wall.

All three are functions of the distance ``r`` (voxels) from the scan's rotation
axis, the same in every slice. The axis is taken parallel to axis 0 (z) through
the centre of the specimen (`rotation_axis`: per slice, the centroid of the
specimen mask, `~synthpack.measure.specimen.specimen_mask`; their median over the
slices): a scanner's specimen is mounted on its rotation axis. An error of the
axis of a voxel or two smears rings over that range of radii (the wall is
measured about its own centre, searched within `WALL_SEARCH` voxels of the axis).

The measure reads at most about `SCANNER_VOXELS` voxels: evenly spaced slices of
the specimen (rings and cupping are constant along z, so a subsample of slices
loses nothing but samples). The slices are grouped into `N_SLABS` slabs of
consecutive slices; what varies between slabs (noise, the grains' structure, the
pore texture) gives each estimate its standard error, so correlated structure
does not pass for an artefact.

**Cupping.** In the grain and the pore interiors
(`~synthpack.measure.spectrum.phase_interiors`, less the voxels that stand out of
their neighbourhood: voids, inclusions) within the field of view, the level is
fitted as ``a + b r^2`` by least squares, after taking off the rings found
(below): the form `~synthpack.artefacts.BeamHardening` applies,
``L (1 - s (1 - (r / R)^2))``, with ``R`` the radius of the field of view as
`BeamHardening` takes it on a slice (half the smaller of Y and X), so that the
strength is ``s = b R^2 / (a + b R^2)``: > 0 a darker centre (cupping), < 0 a
brighter one. The two phases' strengths are combined with inverse-variance
weights; the strength is significant when it exceeds `CUPPING_SIGNIFICANCE`
standard errors.

**Rings.** Each interior voxel, less its phase's fitted level, less its phase's
local mean in the slice (`_detail`: a Gaussian mean of `RING_HIGHPASS` voxels
over the phase's interior, which takes off the grains' own levels, the pore
texture and what is left of a radial trend), is averaged over azimuth and slices
in radius bins of `RING_BIN` voxels. The standard error of each bin is the
larger of ``sigma / sqrt(n)`` (``n`` samples in the bin; ``sigma^2`` the median
over bins of the slabs' variance times their samples: the noise, correlations
included) and the spread of the slabs' profiles at that bin. Rings are found one
at a time (the most significant bin above `RING_SIGNIFICANCE` standard errors, at least
`RING_EDGE` voxels inside the ends of the profile; none again where one was fitted),
and after each the rings found so far are fitted jointly (radii, one common width
and signed amplitudes of the Gaussian ring profiles
`~synthpack.artefacts.RingArtefacts` draws, less their 1D smoothing) and taken
off the profile, so a strong ring's side lobes are not counted as rings. The
amplitudes are then fitted on unit rings passed through the same in-slice
high-pass as the data (`_exact_basis`), and rings whose amplitude is not
significant are dropped.

**Wall.** Outside the specimen, the median intensity in `RING_BIN` radius bins
(those at least half outside the specimen mask, with at least a quarter of their
circle inside the slice). A container wall is the brightest bump of that profile
that stands out by more than `WALL_CONTRAST` of the grain-pore contrast both
above the pore level and above the darkest level beyond it (the air): its
thickness is the bump's width at half its height (over the pore level inward,
over the air outward); its intensity the level that a sharp wall of that
thickness needs to hold the bump's area above the pore level (inward of its
middle) and above the air (outward; a blur keeps areas); its inner radius the
inner half-height crossing. A wall whose intensity lies between the pore level
and the air's cannot be told from the blurred edge of the specimen and is not
detected.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize

from .._shared.text import sig
from .spectrum import phase_interiors

logger = logging.getLogger(__name__)

__all__ = [
    "CUPPING_SIGNIFICANCE",
    "Cupping",
    "N_SLABS",
    "RING_BIN",
    "RING_HIGHPASS",
    "RING_SIGNIFICANCE",
    "Rings",
    "SCANNER_VOXELS",
    "ScannerArtefacts",
    "WALL_CONTRAST",
    "Wall",
    "measure_scanner",
    "rotation_axis",
]

#: The measure reads at most about this many voxels (evenly spaced whole slices of the specimen).
SCANNER_VOXELS = 1 << 24
#: Slabs of consecutive measured slices whose spread gives the standard errors.
N_SLABS = 8
#: Fewer slabs (measured slices) than this: no standard error, cupping and rings not measured.
MIN_SLABS = 4
#: Cupping is on when its strength exceeds this many standard errors.
CUPPING_SIGNIFICANCE = 4.0
#: A ring is a bin of the high-passed radial profile this many standard errors from zero.
RING_SIGNIFICANCE = 5.0
#: Radius bin of the ring profile, voxels.
RING_BIN = 0.5
#: Gaussian sigma (voxels) of the smoothing the ring profile's high-pass takes off.
RING_HIGHPASS = 3.0
#: At most this many rings are fitted.
MAX_RINGS = 32
#: Rings are looked for, and fitted, at least this many voxels inside the outer end of the profile (the
#: specimen's edge: its own boundary makes a step there that the high-pass turns into a spike, no ring), and
#: of its inner end where that is not the axis.
RING_EDGE = 3.0
#: A wall stands out from the pore level and from the air beyond it by this fraction of |contrast|.
WALL_CONTRAST = 0.25
#: The wall's centre is searched within this many voxels of the axis (`RING_BIN` steps).
WALL_SEARCH = 2.0
#: Samples whose detail (`_detail`) lies further than this many robust standard deviations out are left out.
_OUTLIER = 4.0
#: A radius bin needs this many samples.
_MIN_BIN = 20
_FWHM_TO_SIGMA = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))
_WIDTH_BOUNDS = (0.5, 8.0)  # ring FWHM, voxels


@dataclass(frozen=True)
class Cupping:
    """The fitted radial trend of the phase levels (see the module docstring).

    Attributes
    ----------
    strength : float
        `~synthpack.artefacts.BeamHardening` strength (dimensionless): the relative
        darkening of the axis against the rim of the field of view, both phases
        combined; < 0 for a brighter centre.
    error : float
        Its standard error (from the spread of the slabs).
    significant : bool
        ``|strength| > CUPPING_SIGNIFICANCE * error``.
    phases : dict of str to (float, float)
        ``"grains"``, ``"pores"``: each phase's strength and standard error (a phase
        without interior voxels in every slab left out).
    trend : dict of str to (float, float)
        Each phase's fitted ``(a, b)`` of ``level = a + b r^2``, intensity units and
        intensity units per voxel squared.
    field_radius : float
        ``R``, voxels.
    """

    strength: float
    error: float
    significant: bool
    phases: dict[str, tuple[float, float]]
    trend: dict[str, tuple[float, float]]
    field_radius: float


@dataclass(frozen=True)
class Rings:
    """The rings found (see the module docstring).

    Attributes
    ----------
    radii : tuple of float
        Distance of each ring from the axis, voxels.
    amplitudes : tuple of float
        Signed peak of each ring, intensity units.
    width : float
        Common full width at half maximum, voxels (0 when no ring was found).
    floor : float
        The detection limit: `RING_SIGNIFICANCE` times the median standard error of a
        bin of the high-passed profile, intensity units.
    """

    radii: tuple[float, ...]
    amplitudes: tuple[float, ...]
    width: float
    floor: float


@dataclass(frozen=True)
class Wall:
    """The container wall around the specimen (see the module docstring).

    Attributes
    ----------
    intensity : float
        Mean intensity across the wall, intensity units.
    thickness : float
        Width at half height, voxels.
    inner_radius : float
        Distance of its inner face from the axis, voxels.
    gap : float
        ``inner_radius`` less the specimen's radius (the radius of a disc of the
        specimen mask's mean area per slice), voxels.
    air : float
        The darkest level of the profile beyond the wall: the air around the container,
        intensity units.
    """

    intensity: float
    thickness: float
    inner_radius: float
    gap: float
    air: float


@dataclass(frozen=True)
class ScannerArtefacts:
    """What `measure_scanner` found.

    Attributes
    ----------
    axis : (float, float)
        ``(y, x)`` of the rotation axis in every slice, voxels.
    specimen_radius : float
        Radius of a disc of the specimen mask's mean area per slice, voxels.
    cupping : Cupping or None
        None where it could not be measured (fewer than `MIN_SLABS` slices, or no
        phase interior).
    rings : Rings or None
        None where the profile could not be measured; no ring: empty `Rings.radii`.
    wall : Wall or None
        None where the scan shows no wall.
    """

    axis: tuple[float, float]
    specimen_radius: float
    cupping: Cupping | None
    rings: Rings | None
    wall: Wall | None

    def summary(self) -> str:
        """One short line: the axis, the cupping (with its standard error), the rings and the wall found.

        Lengths in voxels (``vx``), intensities to 3 significant figures; every figure is in the ``repr``.
        """
        parts = [f"axis ({sig(self.axis[0])}, {sig(self.axis[1])}) vx"]
        cupping, rings, wall = self.cupping, self.rings, self.wall
        if cupping is None:
            parts.append("cupping not measured")
        else:
            verdict = "" if cupping.significant else " (not significant)"
            parts.append(f"cupping {sig(cupping.strength, 2)} ± {sig(cupping.error, 2)}{verdict}")
        if rings is None:
            parts.append("rings not measured")
        elif not rings.radii:
            parts.append("no ring")
        else:
            peak = max(abs(a) for a in rings.amplitudes)
            parts.append(f"{len(rings.radii)} ring(s) at {sig(min(rings.radii))}-{sig(max(rings.radii))} vx "
                         f"(peak {sig(peak)})")
        parts.append("no wall" if wall is None else
                     f"wall {sig(wall.thickness, 2)} vx thick, intensity {sig(wall.intensity)}")
        return ", ".join(parts)

    def statistics_fields(self) -> dict[str, float | tuple[float, ...] | None]:
        """The `~synthpack.source.SourceStatistics` fields: each None where absent or not significant."""
        cupping, rings, wall = self.cupping, self.rings, self.wall
        found = rings is not None and len(rings.radii) > 0
        return {
            "scan_axis": tuple(self.axis),
            "cupping_strength": cupping.strength if cupping is not None and cupping.significant else None,
            "cupping_error": cupping.error if cupping is not None else None,
            "ring_radii": rings.radii if found else None,
            "ring_amplitudes": rings.amplitudes if found else None,
            "ring_width": rings.width if found else None,
            "wall_intensity": wall.intensity if wall is not None else None,
            "wall_thickness": wall.thickness if wall is not None else None,
            "wall_gap": wall.gap if wall is not None else None,
            "air_intensity": wall.air if wall is not None else None,
        }


def rotation_axis(specimen: np.ndarray) -> tuple[float, float] | None:
    """The scan's rotation axis: the median over slices of the specimen mask's centroid.

    Parameters
    ----------
    specimen : ndarray of bool, shape (Z, Y, X)
        `~synthpack.measure.specimen.specimen_mask`.

    Returns
    -------
    (float, float) or None
        ``(y, x)``, voxels; None for an empty mask.
    """
    counts = specimen.sum(axis=(1, 2)).astype(np.float64)
    occupied = counts > 0
    if not occupied.any():
        return None
    ys = (specimen.sum(axis=2) * np.arange(specimen.shape[1])).sum(axis=1)[occupied] / counts[occupied]
    xs = (specimen.sum(axis=1) * np.arange(specimen.shape[2])).sum(axis=1)[occupied] / counts[occupied]
    return float(np.median(ys)), float(np.median(xs))


def _measured_slices(specimen: np.ndarray, max_voxels: int) -> np.ndarray:
    """Evenly spaced indices of the slices holding specimen, at most ``max_voxels`` voxels in all."""
    occupied = np.flatnonzero(specimen.any(axis=(1, 2)))
    n = min(len(occupied), max(1, max_voxels // (specimen.shape[1] * specimen.shape[2])))
    return occupied[np.unique(np.linspace(0, len(occupied) - 1, n).round().astype(int))]


@dataclass
class _Samples:
    """One phase's interior voxels on the measured slices (flat arrays).

    ``value``: the intensity; ``detail``: the intensity less the phase's local mean in
    the slice (`_detail`); ``radius``: the distance from the axis (voxels); ``slab``.
    """

    value: np.ndarray
    detail: np.ndarray | None
    radius: np.ndarray
    slab: np.ndarray


def _detail(image: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """`image` less its Gaussian mean (sigma `RING_HIGHPASS`) over the `inside` pixels, at those pixels.

    Takes off what varies slowly in the slice (the grains' own levels, the pore phase's
    texture, the cupping) and keeps what is thin: a ring loses about its 1D smoothing in ``r``.
    """
    weight = inside.astype(np.float64)
    mean = ndimage.gaussian_filter(image * weight, RING_HIGHPASS, mode="constant")
    norm = ndimage.gaussian_filter(weight, RING_HIGHPASS, mode="constant")
    return image[inside] - mean[inside] / norm[inside]


def _gather(tomogram: np.ndarray, interiors: dict[str, np.ndarray], slices: np.ndarray, slab_of: np.ndarray,
            radius: np.ndarray, trend: dict[str, tuple[float, float]] | None = None) -> dict[str, _Samples]:
    """Each phase's interior samples of `slices`, without outliers (voids, inclusions: `_typical`).

    With a `trend` (each phase's ``(a, b)`` of ``a + b r^2``), the detail (`_detail`) of the
    intensity less its phase's trend is taken too, and the outliers are those of the detail;
    without, ``detail`` is None and the outliers are those of the intensity.
    """
    samples = {}
    for phase, interior in interiors.items():
        if trend is not None and phase not in trend:
            continue
        values, details, radii, slab = [], [], [], []
        for z, s in zip(slices, slab_of):
            inside = interior[z]
            image = np.asarray(tomogram[z], dtype=np.float64)
            values.append(image[inside])
            if trend is not None:
                details.append(_detail(image - (trend[phase][0] + trend[phase][1] * radius**2), inside))
            radii.append(radius[inside])
            slab.append(np.full(values[-1].size, s, dtype=np.int32))
        value = np.concatenate(values)
        if value.size < _MIN_BIN:
            continue
        detail = np.concatenate(details) if trend is not None else None
        keep = _typical(value if detail is None else detail)
        samples[phase] = _Samples(value[keep], None if detail is None else detail[keep], np.concatenate(radii)[keep],
                                  np.concatenate(slab)[keep])
    return samples


def _typical(values: np.ndarray) -> np.ndarray:
    """Where `values` lie within `_OUTLIER` robust standard deviations (1.4826 MAD) of their median."""
    median = np.median(values)
    spread = 1.4826 * np.median(np.abs(values - median))
    return np.abs(values - median) <= _OUTLIER * spread if spread > 0 else np.ones(values.shape, bool)


def _quadratic_fit(value: np.ndarray, r2: np.ndarray) -> tuple[float, float] | None:
    """Least-squares ``(a, b)`` of ``value = a + b r2``; None when the radii do not vary."""
    design = np.stack([np.ones_like(r2), r2], axis=1)
    if value.size < _MIN_BIN or np.ptp(r2) == 0:
        return None
    (a, b), *_ = np.linalg.lstsq(design, value, rcond=None)
    return float(a), float(b)


def _strength(a: float, b: float, field_radius: float) -> float:
    """BeamHardening's strength of the trend ``a + b r^2`` over a field of view of `field_radius`."""
    rim = a + b * field_radius**2
    return b * field_radius**2 / rim if rim != 0 else 0.0


def _ring_values(radius: np.ndarray, rings: Rings | None) -> np.ndarray | float:
    """The rings' additive profile at `radius` (voxels), intensity units (0 without rings)."""
    if rings is None or not rings.radii:
        return 0.0
    sigma = rings.width * _FWHM_TO_SIGMA
    peaks = np.asarray(rings.amplitudes)[:, None] * np.exp(
        -0.5 * ((radius[None, :] - np.asarray(rings.radii)[:, None]) / sigma) ** 2)
    return peaks.sum(axis=0)


def _cupping(samples: dict[str, _Samples], n_slabs: int, field_radius: float, rings: Rings | None) -> Cupping | None:
    """Fit each phase's ``a + b r^2`` (within `field_radius`, less the `rings`) overall and per slab.

    Returns the strengths and their standard errors (see `Cupping`); None without a phase to fit.
    """
    strengths, per_slab, trend = {}, {}, {}
    for phase, sample in samples.items():
        within = sample.radius <= field_radius
        radius, slab = sample.radius[within], sample.slab[within]
        value, r2 = sample.value[within] - _ring_values(radius, rings), radius**2
        overall = _quadratic_fit(value, r2)
        slab_fits = [_quadratic_fit(value[slab == s], r2[slab == s]) for s in range(n_slabs)]
        if overall is None or any(fit is None for fit in slab_fits):
            continue
        trend[phase] = overall
        strengths[phase] = _strength(*overall, field_radius)
        per_slab[phase] = np.array([_strength(*fit, field_radius) for fit in slab_fits])
    if not strengths:
        return None
    errors = {phase: float(np.std(per_slab[phase], ddof=1) / math.sqrt(n_slabs)) for phase in strengths}
    inverse = {phase: 1.0 / max(error, 1e-12) ** 2 for phase, error in errors.items()}
    weights = {phase: w / sum(inverse.values()) for phase, w in inverse.items()}
    strength = sum(weights[p] * strengths[p] for p in strengths)
    combined = sum(weights[p] * per_slab[p] for p in strengths)
    error = float(np.std(combined, ddof=1) / math.sqrt(n_slabs))
    return Cupping(strength=float(strength), error=error,
                   significant=bool(abs(strength) > CUPPING_SIGNIFICANCE * error),
                   phases={p: (float(strengths[p]), errors[p]) for p in strengths}, trend=trend,
                   field_radius=float(field_radius))


def _ring_basis(radius: np.ndarray, radii: np.ndarray, width: float) -> np.ndarray:
    """Unit Gaussian rings at `radii` of FWHM `width`, less their 1D smoothing as `_detail` takes it: (bins, rings)."""
    sigma = width * _FWHM_TO_SIGMA
    columns = np.exp(-0.5 * ((radius[:, None] - radii[None, :]) / sigma) ** 2)
    step = np.gradient(radius) if len(radius) > 1 else np.ones(1)
    smoothing = RING_HIGHPASS / float(np.median(step))
    return columns - ndimage.gaussian_filter1d(columns, smoothing, axis=0, mode="nearest")


def _fit_rings(profile: np.ndarray, radius: np.ndarray, error: np.ndarray, radii: np.ndarray,
               width: float, span: tuple[float, float]) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Joint fit of ring radii (within 1.5 voxels of `radii`, and within `span`), width and amplitudes to the profile.

    Returns radii, width, amplitudes (intensity units) and the amplitudes' standard errors.
    """
    target = profile / error

    def amplitudes(params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        basis = _ring_basis(radius, params[:-1], params[-1]) / error[:, None]
        coefficients, *_ = np.linalg.lstsq(basis, target, rcond=None)
        return coefficients, basis

    def residual(params: np.ndarray) -> np.ndarray:
        coefficients, basis = amplitudes(params)
        return basis @ coefficients - target

    lower = np.append(np.maximum(radii - 1.5, span[0]), _WIDTH_BOUNDS[0])
    upper = np.append(np.minimum(radii + 1.5, span[1]), _WIDTH_BOUNDS[1])
    start = np.clip(np.append(radii, width), lower, upper)
    fitted = optimize.least_squares(residual, start, bounds=(lower, upper)).x
    coefficients, basis = amplitudes(fitted)
    covariance = np.linalg.pinv(basis.T @ basis)
    return fitted[:-1], float(fitted[-1]), coefficients, np.sqrt(np.maximum(np.diag(covariance), 0.0))


def _exact_basis(interiors: dict[str, np.ndarray], slices: np.ndarray, radius: np.ndarray, bins: np.ndarray,
                 radii: np.ndarray, width: float) -> np.ndarray:
    """Unit rings through `_detail` exactly as the data went, binned like the profile: (len(bins), rings).

    `_detail`'s local mean over a phase's interior patches takes more of a ring off
    than the 1D smoothing `_ring_basis` models where the patches are small; the ring
    amplitudes are fitted on this. It is measured on at most `N_SLABS` of the slices.
    """
    sigma = width * _FWHM_TO_SIGMA
    index = (radius / RING_BIN).astype(np.int64)
    n_bins = int(index.max()) + 1
    columns = []
    for ring in radii:
        image = np.exp(-0.5 * ((radius - ring) / sigma) ** 2)
        sums, counts = np.zeros(n_bins), np.zeros(n_bins)
        for z in slices[np.unique(np.linspace(0, len(slices) - 1, min(N_SLABS, len(slices))).round().astype(int))]:
            for interior in interiors.values():
                inside = interior[z]
                if inside.any():
                    sums += np.bincount(index[inside], _detail(image, inside), minlength=n_bins)
                    counts += np.bincount(index[inside], minlength=n_bins)
        columns.append(np.divide(sums, counts, out=np.zeros(n_bins), where=counts > 0)[bins])
    return np.stack(columns, axis=1)


def _rings(samples: dict[str, _Samples], n_slabs: int, interiors: dict[str, np.ndarray], slices: np.ndarray,
           radius_grid: np.ndarray) -> Rings | None:
    """The radial profile of the interiors' detail (`_detail`), and the rings found in it.

    Found and located with `_ring_basis`; their amplitudes fitted on `_exact_basis`.
    """
    detail = np.concatenate([sample.detail for sample in samples.values()])
    radius = np.concatenate([sample.radius for sample in samples.values()])
    slab = np.concatenate([sample.slab for sample in samples.values()])
    n_bins = int(radius.max() / RING_BIN) + 1
    index = slab * n_bins + (radius / RING_BIN).astype(np.int64)
    size = n_slabs * n_bins
    counts = np.bincount(index, minlength=size).reshape(n_slabs, n_bins).astype(np.float64)
    sums = np.bincount(index, detail, minlength=size).reshape(n_slabs, n_bins)
    count = counts.sum(axis=0)
    valid = (counts > 0).all(axis=0) & (count >= _MIN_BIN)
    if np.count_nonzero(valid) < 3:
        return None
    centre = (np.bincount(index % n_bins, radius, minlength=n_bins) / np.maximum(count, 1.0))[valid]
    profile = sums.sum(axis=0)[valid] / count[valid]
    spread = np.var(sums[:, valid] / counts[:, valid], axis=0, ddof=1)
    sigma = math.sqrt(float(np.median(spread * counts[:, valid].mean(axis=0))))
    error = np.maximum(sigma / np.sqrt(count[valid]), np.sqrt(spread / n_slabs))
    error = np.maximum(error, 1e-12 * max(1.0, float(np.abs(profile).max())))
    floor = RING_SIGNIFICANCE * float(np.median(error))
    inner = centre[0] + RING_EDGE if centre[0] >= RING_EDGE else 0.0
    span = (inner, centre[-1] - RING_EDGE)
    resolvable = (centre >= span[0]) & (centre <= span[1])
    radii, width, amps, amp_errors = np.zeros(0), 1.5, np.zeros(0), np.zeros(0)
    while len(radii) < MAX_RINGS and resolvable.any():
        model = _ring_basis(centre, radii, width) @ amps if len(radii) else 0.0
        z = np.where(resolvable, (profile - model) / error, 0.0)
        peak = int(np.argmax(np.abs(z)))
        if abs(z[peak]) < RING_SIGNIFICANCE or np.any(np.abs(radii - centre[peak]) < RING_BIN):
            break  # nothing more, or what is left at a ring already fitted is not a ring's shape
        radii, width, amps, amp_errors = _fit_rings(profile, centre, error, np.append(radii, centre[peak]), width,
                                                    span)
    if len(radii):
        basis = _exact_basis(interiors, slices, radius_grid, np.flatnonzero(valid), radii, width) / error[:, None]
        amps, *_ = np.linalg.lstsq(basis, profile / error, rcond=None)
        amp_errors = np.sqrt(np.maximum(np.diag(np.linalg.pinv(basis.T @ basis)), 0.0))
    keep = np.abs(amps) > RING_SIGNIFICANCE * amp_errors
    radii, amps = radii[keep], amps[keep]
    order = np.argsort(radii)
    return Rings(radii=tuple(float(r) for r in radii[order]), amplitudes=tuple(float(a) for a in amps[order]),
                 width=float(width) if len(radii) else 0.0, floor=floor)


def _wall_centre(tomogram: np.ndarray, specimen: np.ndarray, slices: np.ndarray, axis: tuple[float, float],
                 specimen_radius: float) -> tuple[float, float]:
    """The centre within `WALL_SEARCH` voxels of `axis` about which the outside's brightest annulus is brightest.

    The sharpest circle: a wall a voxel off its centre is smeared over two voxels of radius.
    Mean intensities in `RING_BIN` bins outside the specimen and `specimen_radius` are compared.
    """
    outside = ~specimen[slices]
    values = np.asarray(tomogram[slices], dtype=np.float64)[outside]
    where = np.nonzero(outside)
    best, centre = -np.inf, axis
    steps = np.arange(-WALL_SEARCH, WALL_SEARCH + 1e-9, RING_BIN)
    for dy in steps:
        for dx in steps:
            radius = np.hypot(where[1] - (axis[0] + dy), where[2] - (axis[1] + dx))
            keep = radius > specimen_radius
            if not keep.any():
                return axis
            index = (radius[keep] / RING_BIN).astype(np.int64)
            count = np.bincount(index)
            mean = np.bincount(index, values[keep]) / np.maximum(count, 1)
            peak = float(mean[count >= _MIN_BIN].max(initial=-np.inf))
            if peak > best:
                best, centre = peak, (axis[0] + float(dy), axis[1] + float(dx))
    return centre


def _wall(tomogram: np.ndarray, specimen: np.ndarray, slices: np.ndarray, axis: tuple[float, float],
          specimen_radius: float, pore_level: float, contrast: float) -> Wall | None:
    """The container wall in the radial profile outside the specimen (see the module docstring)."""
    ny, nx = specimen.shape[1:]
    centre = _wall_centre(tomogram, specimen, slices, axis, specimen_radius)
    radius = np.hypot(np.arange(ny)[:, None] - centre[0], np.arange(nx)[None, :] - centre[1])
    n_bins = int(radius.max() / RING_BIN) + 1
    bins = (radius / RING_BIN).astype(np.int64)
    in_slice = np.bincount(bins.ravel(), minlength=n_bins)
    circle = 2.0 * np.pi * (np.arange(n_bins) + 0.5) * RING_BIN**2  # pixels of a whole annulus
    values, index, outside_count = [], [], np.zeros(n_bins)
    for z in slices:
        outside = ~specimen[z]
        values.append(np.asarray(tomogram[z], dtype=np.float64)[outside])
        index.append(bins[outside])
        outside_count += np.bincount(bins[outside], minlength=n_bins)
    value, index = np.concatenate(values), np.concatenate(index)
    order = np.argsort(index, kind="stable")
    value, index = value[order], index[order]
    usable = ((outside_count >= 0.5 * in_slice * len(slices)) & (outside_count >= _MIN_BIN)
              & (in_slice >= 0.25 * circle) & ((np.arange(n_bins) + 1) * RING_BIN > specimen_radius))
    bins_used = np.flatnonzero(usable)
    if len(bins_used) < 3:
        return None
    bins_used = bins_used[: np.argmax(np.diff(np.append(bins_used, -1)) != 1) + 1]  # the first contiguous run
    starts = np.searchsorted(index, bins_used)
    stops = np.searchsorted(index, bins_used, side="right")
    profile = np.array([np.median(value[a:b]) for a, b in zip(starts, stops)])
    r = (bins_used + 0.5) * RING_BIN
    threshold = WALL_CONTRAST * abs(contrast)
    beyond = np.minimum.accumulate(profile[::-1])[::-1]  # the darkest level at or beyond each radius
    beyond = np.append(beyond[1:], np.inf)
    height = np.minimum(profile - pore_level, profile - beyond)
    if len(profile) < 3 or not (height[:-1] > threshold).any():
        return None
    peak = int(np.argmax(np.where(np.arange(len(profile)) < len(profile) - 1, height, -np.inf)))
    top, air = profile[peak], beyond[peak]
    inner = _crossing(profile, r, peak, -1, (top + pore_level) / 2.0)
    outer = _crossing(profile, r, peak, +1, (top + air) / 2.0)
    middle = (inner + outer) / 2.0
    darkest = peak + int(np.argmin(profile[peak:]))
    inside, beyond_wall = r < middle, (r >= middle) & (np.arange(len(r)) <= darkest)
    excess = (profile[inside] - pore_level).sum() * RING_BIN + (profile[beyond_wall] - air).sum() * RING_BIN
    intensity = float((pore_level + air) / 2.0 + excess / max(outer - inner, RING_BIN))
    return Wall(intensity=intensity, thickness=float(outer - inner), inner_radius=float(inner),
                gap=float(inner - specimen_radius), air=float(air))


def _crossing(profile: np.ndarray, r: np.ndarray, peak: int, step: int, level: float) -> float:
    """Radius where `profile` first falls to `level` going from `peak` in direction `step` (linear between bins)."""
    i = peak
    while 0 <= i + step < len(profile) and profile[i + step] > level:
        i += step
    j = i + step
    if not 0 <= j < len(profile):
        return float(r[i] + step * 0.5)
    fraction = (profile[i] - level) / (profile[i] - profile[j])
    return float(r[i] + step * fraction * abs(r[j] - r[i]))


def measure_scanner(
    tomogram: np.ndarray,
    labels: np.ndarray,
    specimen: np.ndarray,
    distance: np.ndarray,
    *,
    pore_level: float,
    grain_level: float,
    region: np.ndarray | None = None,
    max_voxels: int = SCANNER_VOXELS,
) -> ScannerArtefacts | None:
    """Measure the scan's cupping, rings and container wall about its rotation axis.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities.
    labels : ndarray of int, shape (Z, Y, X)
        0 = pore, > 0 = grain.
    specimen : ndarray of bool, shape (Z, Y, X)
        `~synthpack.measure.specimen.specimen_mask` of `labels`.
    distance : ndarray of float32, shape (Z, Y, X)
        `~synthpack.measure.edges.signed_distance` of `labels`.
    pore_level, grain_level : float
        The phase levels (`~synthpack.measure.phases.estimate_phases`), intensity units.
    region : ndarray of bool, shape (Z, Y, X), optional
        The part of the specimen the phase interiors are sampled from, and whose
        slices are read (a held-out test block taken out); default all of
        `specimen`. The axis and the wall's geometry come from `specimen`.
    max_voxels : int
        Read at most about this many voxels (whole slices).

    Returns
    -------
    ScannerArtefacts or None
        None for an empty specimen.
    """
    axis = rotation_axis(specimen)
    if axis is None:
        return None
    ny, nx = specimen.shape[1:]
    radius = np.hypot(np.arange(ny)[:, None] - axis[0], np.arange(nx)[None, :] - axis[1]).astype(np.float64)
    region = specimen if region is None else region
    slices = _measured_slices(region, max_voxels)
    specimen_radius = math.sqrt(float(specimen[slices].sum()) / len(slices) / math.pi)
    wall = _wall(tomogram, specimen, slices, axis, specimen_radius, pore_level, grain_level - pore_level)
    n_slabs = min(N_SLABS, len(slices))
    cupping, rings = None, None
    if n_slabs >= MIN_SLABS:
        slab_of = np.arange(len(slices)) * n_slabs // len(slices)
        interiors = phase_interiors(distance, region)
        field = min(ny, nx) / 2.0
        first = _cupping(_gather(tomogram, interiors, slices, slab_of, radius), n_slabs, field, None)
        if first is not None:
            samples = _gather(tomogram, interiors, slices, slab_of, radius, first.trend)
            rings = _rings(samples, n_slabs, interiors, slices, radius)
            cupping = _cupping(samples, n_slabs, field, rings)
    else:
        logger.warning("only %d slices hold specimen: cupping and rings not measured", len(slices))
    artefacts = ScannerArtefacts(axis=axis, specimen_radius=specimen_radius, cupping=cupping, rings=rings,
                                 wall=wall)
    logger.info("scanner: %s", artefacts.summary())
    logger.debug("scanner artefacts: %r", artefacts)
    return artefacts
