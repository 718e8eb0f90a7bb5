"""Two built-in, seeded, labelled sample scans of a grain pack.

`sample_scan` returns a `~synthpack.scan.core.Scan` that stands in for a user's own
labelled CT scan of sand, one for each of the paper's two kinds of dataset:

``"large"``
    128 x 128 x 128 voxels of 10.0 um, grains about 18-26 voxels across
    (roughly 250-400 labelled grains, counting those cut by the border).
``"small"``
    128 x 128 x 128 voxels of 5.0 um, grains about 9-13 voxels across
    (roughly 1,500-2,500 labelled grains).

These are STAND-INS, NOT MEASUREMENTS of a real material: the grains, their
arrangement, the voxel sizes and the intensities are all invented by the
generator below. They exist so that the pipeline, the tests and the examples run
without a user's data; any number derived from them says nothing about real sand.

How a sample is made (all of it vectorised NumPy/SciPy, a loop over grains works
on each grain's own bounding box only):

1. Grain seeds are placed by random sequential addition with a minimum distance
   (a Poisson-disc-like set) in a box one grain larger than the volume, so that
   grains cut by the volume's border are present, as in a real crop.
2. Each grain is a random star-shaped body: an ellipsoid of random aspect ratio
   (axes 1 : 0.55-0.95 : 0.55-0.95) and random orientation whose radius is
   modulated by a few random low-frequency waves over the directions, cut by a
   few random planes (flat facets, so the grains are angular rather than round).
3. Every voxel goes to the grain with the smallest normalised distance
   ``|x - c| / r(direction)`` (a competitive growth, so neighbours meet along
   shared faces); it is solid where that distance is below a threshold chosen
   so that 62 % of the volume is solid. Each label is then opened with the
   6-neighbour cross (removing one-voxel slivers) and reduced to its largest
   face-connected component; tiny pieces (mostly grains only grazing the
   border) become pore, and labels are renumbered 1..N. The packing fraction
   that results is about 0.59-0.62.
4. The tomogram is rendered from the labels: each grain has its own mean
   intensity (about 0.75, a few % spread) and a faint internal texture, voxels
   at grain-grain contacts are slightly darker (the thin gap a real scan shows),
   the pore phase is darker (about 0.20) with its own low-frequency texture; the
   image is blurred with a Gaussian (partial-volume edges) and slightly
   correlated Gaussian noise is added (about 4 % of the grain-pore contrast).

The same name and seed give byte-identical arrays; nothing is cached to disk.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..errors import SynthpackInputError
from .core import Scan

logger = logging.getLogger(__name__)

__all__ = ["SAMPLE_NAMES", "sample_scan"]

SAMPLE_NAMES: tuple[str, ...] = ("large", "small")


@dataclass(frozen=True)
class _SampleSpec:
    """Generator parameters of one sample (lengths in voxels unless stated).

    `diameter_range` bounds the nominal (volume-equivalent) grain diameters;
    `growth_fraction` is the solid fraction right after the competitive growth,
    before the clean-up removes a few % of it; `seed_spacing` times the mean
    nominal diameter of two grains is the least distance between their seeds;
    `max_threshold` bounds the growth threshold (and so each grain's reach);
    intensities are in the tomogram's arbitrary units, `noise_fraction` and
    `contact_darkening` are fractions of the grain-pore contrast.
    """

    shape: tuple[int, int, int]
    voxel_size_um: float
    diameter_range: tuple[float, float]
    growth_fraction: float = 0.62
    seed_spacing: float = 0.85
    aspect_range: tuple[float, float] = (0.55, 0.95)
    harmonic_terms: int = 5
    harmonic_amplitude: float = 0.07
    facets: int = 8
    facet_depth: tuple[float, float] = (0.60, 0.90)
    max_threshold: float = 1.5
    min_voxels: int = 20
    grain_intensity: float = 0.75
    grain_spread: float = 0.025
    grain_texture: float = 0.012
    pore_intensity: float = 0.20
    pore_texture: float = 0.015
    contact_darkening: float = 0.20
    blur_sigma: float = 0.8
    noise_fraction: float = 0.04


_SPECS: dict[str, _SampleSpec] = {
    "large": _SampleSpec(
        shape=(128, 128, 128), voxel_size_um=10.0, diameter_range=(18.0, 26.0),
        min_voxels=30, blur_sigma=0.9,
    ),
    "small": _SampleSpec(
        shape=(128, 128, 128), voxel_size_um=5.0, diameter_range=(9.0, 13.0),
        min_voxels=8, blur_sigma=0.75,
    ),
}

# Unit directions used to measure each random shape's extent (its bounding box).
_N_PROBE_DIRECTIONS = 400


def sample_scan(name: str, seed: int = 0) -> Scan:
    """Generate one of the built-in stand-in sample scans.

    Parameters
    ----------
    name : {"large", "small"}
        Which sample: ``"large"`` has grains about 18-26 voxels across (voxel
        10.0 um), ``"small"`` grains about 9-13 voxels across (voxel 5.0 um).
    seed : int, optional
        Seed of the generator; the same name and seed give byte-identical
        arrays, another seed another pack.

    Returns
    -------
    Scan
        ``tomogram``: float32, shape (128, 128, 128), pores about 0.20 and grains
        about 0.75 (arbitrary intensity units), blurred and noisy.
        ``labels``: int32, same shape, 0 = pore, 1..N = grains, each one
        face-connected component. ``voxel_size``: isotropic, in ``"um"``.
        ``source``: ``"sample:<name>"``. ``metadata``: the generator parameters,
        the seed, the number of grains and the achieved packing fraction.

    Raises
    ------
    SynthpackInputError
        If `name` is not one of `SAMPLE_NAMES` or `seed` is not a non-negative
        integer.
    """
    if name not in _SPECS:
        raise SynthpackInputError(
            f"unknown sample {name!r}: choose one of {', '.join(SAMPLE_NAMES)}"
        )
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SynthpackInputError(
            f"sample seed {seed!r} is not usable: give a non-negative integer, e.g. 0"
        )
    spec = _SPECS[name]
    started = time.perf_counter()
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), SAMPLE_NAMES.index(name)]))

    centres, diameters = _place_seeds(rng, spec)
    best_d, owner = _competitive_growth(rng, spec, centres, diameters)
    threshold = _threshold_for_fraction(best_d, spec.growth_fraction, spec.max_threshold)
    labels = _clean_labels(_open_labels(np.where(best_d < threshold, owner, 0)), spec.min_voxels)
    tomogram = _render(rng, spec, labels)

    n_grains = int(labels.max())
    fraction = float(np.count_nonzero(labels)) / labels.size
    metadata = {
        "generator": "synthpack.samples",
        "sample": name,
        "seed": int(seed),
        "stand_in": True,
        "n_grains": n_grains,
        "packing_fraction_achieved": round(fraction, 4),
        "growth_threshold": round(float(threshold), 4),
        **_spec_as_plain_dict(spec),
    }
    logger.info(
        "sample %r (seed %d): %d grains, packing fraction %.3f, %.2f s",
        name, seed, n_grains, fraction, time.perf_counter() - started,
    )
    size = spec.voxel_size_um
    return Scan(tomogram, labels, voxel_size=(size, size, size), unit="um",
                source=f"sample:{name}", metadata=metadata)


def _spec_as_plain_dict(spec: _SampleSpec) -> dict:
    """Return the spec as a dict of plain Python values (tuples become lists)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(spec).items()}


def _place_seeds(rng: np.random.Generator, spec: _SampleSpec) -> tuple[np.ndarray, np.ndarray]:
    """Random sequential addition of grain seeds with a size-dependent minimum distance.

    Returns
    -------
    centres : ndarray, shape (n, 3), float64
        Seed positions (z, y, x) in voxels; they cover the volume plus a margin of
        half the largest diameter on every side.
    diameters : ndarray, shape (n,), float64
        Nominal diameter of each grain in voxels.
    """
    d_lo, d_hi = spec.diameter_range
    margin = d_hi / 2.0
    lo = np.full(3, -margin)
    hi = np.asarray(spec.shape, dtype=float) - 1.0 + margin
    mean_volume = np.pi / 6.0 * (d_hi**4 - d_lo**4) / (4.0 * (d_hi - d_lo))
    n_target = int(round(spec.growth_fraction * np.prod(hi - lo) / mean_volume))

    centres = np.empty((0, 3))
    diameters = np.empty(0)
    for _ in range(60):
        if len(centres) >= n_target:
            break
        batch = max(4 * (n_target - len(centres)), 64)
        cand = lo + rng.random((batch, 3)) * (hi - lo)
        cand_d = rng.uniform(d_lo, d_hi, batch)
        keep = np.ones(batch, dtype=bool)
        if len(centres):
            near = cKDTree(cand).sparse_distance_matrix(
                cKDTree(centres), spec.seed_spacing * d_hi, output_type="ndarray")
            clash = near["v"] < spec.seed_spacing * (cand_d[near["i"]] + diameters[near["j"]]) / 2.0
            keep[near["i"][clash]] = False
        pairs = cKDTree(cand).query_pairs(spec.seed_spacing * d_hi, output_type="ndarray")
        if len(pairs):
            gap = np.linalg.norm(cand[pairs[:, 0]] - cand[pairs[:, 1]], axis=1)
            clash = gap < spec.seed_spacing * (cand_d[pairs[:, 0]] + cand_d[pairs[:, 1]]) / 2.0
            keep[np.maximum(pairs[clash, 0], pairs[clash, 1])] = False
        take = np.flatnonzero(keep)[: n_target - len(centres)]
        centres = np.vstack([centres, cand[take]])
        diameters = np.concatenate([diameters, cand_d[take]])
    if len(centres) < n_target:
        logger.debug("seed placement saturated at %d of %d grains", len(centres), n_target)
    return centres, diameters


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    """Return `n` random unit vectors, shape (n, 3), uniform on the sphere."""
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


class _GrainShape:
    """One random star-shaped grain in its own frame (lengths in voxels).

    The smooth body is an ellipsoid with semi-axes `radii` whose radius along a
    unit direction ``u`` is multiplied by ``1 + sum_m amp_m cos(freq_m u.dir_m +
    phase_m)``; it is cut by planes with unit normals `facet_normals`, each at
    `facet_depth` (a fraction) of the smooth radius along its normal.
    """

    def __init__(
        self,
        radii: np.ndarray,
        wave_dirs: np.ndarray,
        wave_freq: np.ndarray,
        wave_phase: np.ndarray,
        wave_amp: np.ndarray,
        facet_normals: np.ndarray,
        facet_depth: np.ndarray,
    ) -> None:
        self._inv_radii = (1.0 / radii).astype(np.float32)
        self._wave_matrix = (wave_dirs.T * wave_freq).astype(np.float32)  # (3, m)
        self._wave_phase = wave_phase.astype(np.float32)
        self._wave_amp = wave_amp.astype(np.float32)
        facet_dist = self.radius(facet_normals) * facet_depth
        self._facet_matrix = (facet_normals / facet_dist[:, None]).astype(np.float32)  # (k, 3)

    def radius(self, u: np.ndarray) -> np.ndarray:
        """Smooth radius along unit directions `u`, shape (n, 3) -> (n,), float32."""
        u = u.astype(np.float32, copy=False)
        scaled = u * self._inv_radii
        ellipsoid = 1.0 / np.sqrt(np.einsum("ij,ij->i", scaled, scaled))
        waves = np.cos(_times_matrix(u, self._wave_matrix) + self._wave_phase)
        return ellipsoid * (1.0 + np.einsum("ij,j->i", waves, self._wave_amp))

    def gauge(self, p: np.ndarray) -> np.ndarray:
        """Normalised distance of local points `p`, shape (n, 3) -> (n,), float32.

        Below 1 inside the grain, 1 on its surface; it grows linearly along each ray
        from the grain's centre.
        """
        p = p.astype(np.float32, copy=False)
        t = np.sqrt(np.einsum("ij,ij->i", p, p))
        smooth = t / self.radius(p / np.maximum(t, np.float32(1e-6))[:, None])
        f = self._facet_matrix[:, :, None]  # (k, 3, 1): plane rows against points as columns
        planes = (f[:, 0] * p[:, 0] + f[:, 1] * p[:, 1] + f[:, 2] * p[:, 2]).max(axis=0)
        return np.maximum(smooth, planes)


def _times_matrix(rows: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``rows @ matrix`` for rows of shape (n, 3) and a (3, m) matrix, without BLAS.

    Element-wise NumPy avoids multithreaded BLAS calls on these thin products,
    whose thread start-up dominates (and stalls on a busy machine).
    """
    return rows[:, 0:1] * matrix[0] + rows[:, 1:2] * matrix[1] + rows[:, 2:3] * matrix[2]


def _random_shape(rng: np.random.Generator, spec: _SampleSpec, diameter: float) -> _GrainShape:
    """Draw a grain shape whose ellipsoid has the volume of a sphere of `diameter` voxels."""
    b = rng.uniform(*spec.aspect_range)
    c = rng.uniform(spec.aspect_range[0], b)
    axes = np.array([1.0, b, c])
    m = spec.harmonic_terms
    return _GrainShape(
        radii=diameter / 2.0 * axes / np.cbrt(np.prod(axes)),
        wave_dirs=_unit_vectors(rng, m),
        wave_freq=rng.uniform(2.0, 4.5, m),
        wave_phase=rng.uniform(0.0, 2 * np.pi, m),
        wave_amp=spec.harmonic_amplitude * rng.uniform(0.5, 1.0, m),
        facet_normals=_unit_vectors(rng, spec.facets),
        facet_depth=rng.uniform(*spec.facet_depth, spec.facets),
    )


def _competitive_growth(
    rng: np.random.Generator, spec: _SampleSpec, centres: np.ndarray, diameters: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Give every voxel to the grain with the smallest normalised distance.

    Returns
    -------
    best_d : ndarray, float32, shape `spec.shape`
        Smallest normalised distance over all grains (inf beyond every grain's reach).
    owner : ndarray, int32, shape `spec.shape`
        1-based index of that grain (0 where `best_d` is inf).
    """
    shape = np.asarray(spec.shape)
    best_d = np.full(spec.shape, np.inf, dtype=np.float32)
    owner = np.zeros(spec.shape, dtype=np.int32)
    rotations = Rotation.from_quat(rng.normal(size=(len(centres), 4))).as_matrix()
    probes = _unit_vectors(rng, _N_PROBE_DIRECTIONS)
    reach = spec.max_threshold
    for index, (centre, diameter, rot) in enumerate(zip(centres, diameters, rotations), start=1):
        grain = _random_shape(rng, spec, diameter)
        # Extent along each volume axis: local probe points rotated to the volume frame.
        surface = probes * grain.radius(probes)[:, None]
        half = reach * np.abs(_times_matrix(surface, rot.T)).max(axis=0) + 1.0
        start = np.maximum(np.floor(centre - half).astype(int), 0)
        stop = np.minimum(np.ceil(centre + half).astype(int) + 1, shape)
        if np.any(stop <= start):
            continue
        # Offsets from the centre along each axis.
        z, y, x = (np.arange(a, b, dtype=np.float32) - np.float32(c)
                   for a, b, c in zip(start, stop, centre))
        r_max = 1.05 * float(np.linalg.norm(surface, axis=1).max()) + 0.5
        distance = np.sqrt(z[:, None, None] ** 2 + y[None, :, None] ** 2 + x[None, None, :] ** 2)
        box = tuple(slice(a, b) for a, b in zip(start, stop))
        box_d, box_owner = best_d[box], owner[box]
        # The gauge is at least distance / r_max: skip voxels it cannot win.
        where = np.nonzero(distance < np.float32(r_max) * np.minimum(box_d, np.float32(reach)))
        # Local coordinates rot.T @ (x - c), as row vectors (x - c) @ rot.
        rot32 = rot.astype(np.float32)
        local = (z[where[0], None] * rot32[0] + y[where[1], None] * rot32[1]
                 + x[where[2], None] * rot32[2])
        d = grain.gauge(local)
        better = d < box_d[where]
        where = tuple(w[better] for w in where)
        box_d[where] = d[better]
        box_owner[where] = index
    return best_d, owner


def _threshold_for_fraction(best_d: np.ndarray, fraction: float, ceiling: float) -> float:
    """Normalised-distance threshold under which `fraction` of the voxels lie (at most `ceiling`)."""
    threshold = float(np.quantile(best_d, fraction))
    if not threshold < ceiling:
        logger.debug("growth threshold capped at %.2f (packing fraction not reached)", ceiling)
        threshold = ceiling
    return threshold


def _open_labels(labels: np.ndarray) -> np.ndarray:
    """Morphological opening of every label with the 6-neighbour cross.

    Removes the one-voxel slivers that competitive growth leaves where a grain's
    tip reaches into a narrow gap between its neighbours. The volume border does
    not erode (grains cut by it keep their cut face).

    Parameters
    ----------
    labels : ndarray, int32, shape (Z, Y, X)
        Labels, 0 = pore.

    Returns
    -------
    ndarray, int32, shape (Z, Y, X)
        The labels with every voxel outside its own label's opening set to 0.
    """
    interior = labels.copy()
    for head, tail in _face_neighbour_pairs():
        differ = labels[head] != labels[tail]
        interior[head][differ] = 0
        interior[tail][differ] = 0
    opened = interior.copy()
    for head, tail in _face_neighbour_pairs():
        for here, there in ((head, tail), (tail, head)):
            grow = (interior[there] != 0) & (interior[there] == labels[here])
            opened[here][grow] = labels[here][grow]
    return opened


def _face_neighbour_pairs() -> list[tuple[tuple[slice, ...], tuple[slice, ...]]]:
    """Slices ``(head, tail)`` pairing every voxel with its face neighbour along z, y and x.

    ``volume[head]`` and ``volume[tail]`` have the same shape, and element ``i`` of
    one is the face neighbour of element ``i`` of the other.
    """
    pairs = []
    for axis in range(3):
        head = [slice(None)] * 3
        tail = [slice(None)] * 3
        head[axis], tail[axis] = slice(1, None), slice(None, -1)
        pairs.append((tuple(head), tuple(tail)))
    return pairs


def _clean_labels(owner: np.ndarray, min_voxels: int) -> np.ndarray:
    """Keep each label's largest face-connected piece, drop small grains, renumber 1..N.

    Parameters
    ----------
    owner : ndarray, int32, shape (Z, Y, X)
        Raw labels (0 = pore), possibly with several pieces per label.
    min_voxels : int
        Grains with fewer voxels (after keeping the largest piece) become pore.

    Returns
    -------
    ndarray, int32, shape (Z, Y, X)
        Labels 0..N, consecutive, each positive label one face-connected component,
        in the order of the raw labels they come from.
    """
    labels = owner.copy()
    for index, box in enumerate(ndimage.find_objects(owner), start=1):
        if box is None:
            continue
        mine = owner[box] == index
        pieces, n_pieces = ndimage.label(mine)
        if n_pieces > 1:
            sizes = np.bincount(pieces.ravel())
            sizes[0] = 0
            labels[box][mine & (pieces != np.argmax(sizes))] = 0
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    kept = np.flatnonzero(counts >= min_voxels)
    lookup = np.zeros(len(counts), dtype=np.int32)
    lookup[kept] = np.arange(1, len(kept) + 1, dtype=np.int32)
    return lookup[labels]


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, ...], sigma: float) -> np.ndarray:
    """Gaussian-filtered white noise of unit standard deviation, float32."""
    field = ndimage.gaussian_filter(rng.standard_normal(shape, dtype=np.float32), sigma)
    return field / max(float(field.std()), 1e-12)


def _render(rng: np.random.Generator, spec: _SampleSpec, labels: np.ndarray) -> np.ndarray:
    """Render a CT-like float32 tomogram of `labels` (see the module docstring)."""
    n = int(labels.max())
    contrast = spec.grain_intensity - spec.pore_intensity
    grain_means = spec.grain_intensity * (1.0 + spec.grain_spread * rng.standard_normal(n + 1))
    grain_means[0] = spec.pore_intensity
    image = grain_means.astype(np.float32)[labels]
    solid = labels > 0
    image += np.where(
        solid,
        spec.grain_texture * _smooth_noise(rng, spec.shape, 1.5),
        spec.pore_texture * _smooth_noise(rng, spec.shape, 6.0),
    ).astype(np.float32)
    # Voxels of a grain next to another grain: the thin gap at a contact.
    contact = np.zeros_like(solid)
    for head, tail in _face_neighbour_pairs():
        differ = (labels[head] != labels[tail]) & solid[head] & solid[tail]
        contact[head] |= differ
        contact[tail] |= differ
    image[contact] -= np.float32(spec.contact_darkening * contrast)
    image = ndimage.gaussian_filter(image, spec.blur_sigma)
    image += np.float32(spec.noise_fraction * contrast) * _smooth_noise(rng, spec.shape, 0.5)
    return image.astype(np.float32)
