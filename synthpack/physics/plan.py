"""The pour plan: which grains fall, how they are turned and scaled, and where they spawn.

Every random choice of a pour is made here, from one seed (a NumPy ``Generator``), so
a plan, and with a deterministic engine the whole pour, is reproducible.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from .._shared.seeds import generator
from ..errors import SynthpackInputError
from ..library.sampling import draw
from .container import LibraryLike, Tube

logger = logging.getLogger(__name__)

__all__ = ["PourPlan", "make_plan", "parse_scale", "parse_size_classes", "SPAWN_GAP"]

#: Clearance between bounding spheres of neighbouring spawn points, as a fraction
#: of the batch's largest bounding-sphere radius.
SPAWN_GAP = 0.1
_SPAWN_CANDIDATES = 16  # random disc points tried per grain when spawning


@dataclass(frozen=True)
class PourPlan:
    """Everything drawn at random for one pour, physical units.

    Attributes
    ----------
    indices : numpy.ndarray
        (N,) int64 library index of each grain, in pouring order.
    quaternions : numpy.ndarray
        (N, 4) float64 unit quaternions (w, x, y, z), local -> world, at spawn.
    scales : numpy.ndarray
        (N,) float64 scale factor of each grain (about its local origin).
    batches : numpy.ndarray
        (N,) int64 batch number (0-based, non-decreasing).
    spawn_offsets : numpy.ndarray
        (N, 3) float64 ``(x, y, dz)``: world x, y of the grain's local origin and its
        height above the pack top when its batch starts, physical units.
    bounding_radii : numpy.ndarray
        (N,) float64 radius of the sphere about the local origin that holds the
        scaled grain, physical units.
    seed : int
        Seed all of the above was drawn from.
    """

    indices: np.ndarray
    quaternions: np.ndarray
    scales: np.ndarray
    batches: np.ndarray
    spawn_offsets: np.ndarray
    bounding_radii: np.ndarray
    seed: int

    def __len__(self) -> int:
        return int(self.indices.shape[0])

    @property
    def n_batches(self) -> int:
        """Number of batches."""
        return int(self.batches.max()) + 1 if len(self) else 0


def parse_scale(scale: float | Sequence[float]) -> tuple[float, float]:
    """Validate a scale factor: a positive number or a ``(min, max)`` range.

    Returns
    -------
    tuple of 2 float
        ``(low, high)``; equal for a fixed scale.
    """
    if np.ndim(scale) == 0:
        low = high = _positive_float(scale, "scale")
    else:
        values = list(scale)  # type: ignore[arg-type]
        if len(values) != 2:
            raise SynthpackInputError(
                f"scale must be a number or a (min, max) pair, got {scale!r}."
            )
        low = _positive_float(values[0], "scale minimum")
        high = _positive_float(values[1], "scale maximum")
        if high < low:
            raise SynthpackInputError(
                f"scale range ({low:g}, {high:g}) has max < min; give (min, max)."
            )
    return low, high


def parse_size_classes(
    size_classes: Sequence[Sequence[float]] | None,
) -> list[tuple[float, float, float]] | None:
    """Validate size classes ``[(d_min, d_max, fraction), ...]``.

    Diameters are equivalent diameters in physical units (half-open ``[d_min,
    d_max)``); fractions are NUMBER fractions of the grains poured and are
    normalised to sum to one.

    Returns
    -------
    list of (float, float, float) or None
        Classes with normalised fractions; None if `size_classes` is None.
    """
    if size_classes is None:
        return None
    classes = []
    for item in size_classes:
        try:
            d_min, d_max, fraction = (float(v) for v in item)
        except (TypeError, ValueError):
            raise SynthpackInputError(
                f"Each size class must be (d_min, d_max, fraction), got {item!r}."
            ) from None
        if not (0 <= d_min < d_max) or not math.isfinite(d_min):
            raise SynthpackInputError(
                f"Size class ({d_min:g}, {d_max:g}) needs 0 <= d_min < d_max (equivalent "
                "diameters in the library's unit)."
            )
        if not (fraction >= 0 and math.isfinite(fraction)):
            raise SynthpackInputError(
                f"Size class fraction must be a finite number >= 0, got {fraction!r}."
            )
        classes.append((d_min, d_max, fraction))
    total = sum(c[2] for c in classes)
    if not classes or total <= 0:
        raise SynthpackInputError(
            "size_classes must hold at least one class with a positive fraction, "
            "e.g. [(150, 250, 0.7), (250, 400, 0.3)]."
        )
    return [(a, b, f / total) for a, b, f in classes]


def make_plan(
    library: LibraryLike,
    n_particles: int,
    batch_size: int,
    tube: Tube,
    *,
    seed: int = 0,
    scale: float | Sequence[float] = 1.0,
    size_classes: Sequence[Sequence[float]] | None = None,
    indices: Sequence[int] | None = None,
) -> PourPlan:
    """Draw the grains, orientations, scales and spawn points of a pour.

    Grains are drawn from `library` with replacement, each as often as its
    ``draw_weights`` say (the field of view's bias against large grains undone:
    `synthpack.library.sampling`), over the whole library or per size class (the
    paper's sifting) with each class's number fraction, then shuffled so
    classes mix across batches. Orientations are uniform on SO(3); scales uniform in
    the `scale` range. Batch ``b`` holds grains ``b*batch_size ..``. Spawn points of a
    batch are found by random sequential deposition of the grains' bounding spheres
    (about their local origins, plus a gap) inside the tube's disc, above the pack
    top, so that no two grains overlap at spawn and none overlaps the wall, the
    floor or the grains already placed (see :func:`_spawn_points`).

    Parameters
    ----------
    library : ParticleLibrary
        Needs ``len``, ``[i].mesh``, ``equivalent_diameters`` and ``draw_weights``.
    n_particles : int
        Number of grains, >= 1.
    batch_size : int
        Grains per batch, >= 1.
    tube : Tube
        Container, physical units.
    seed : int
        Seed of the NumPy generator every draw comes from.
    scale : float or (float, float)
        Scale factor, or a range to draw it uniformly from, per grain.
    size_classes : sequence of (d_min, d_max, fraction), optional
        Target size distribution by number; see :func:`parse_size_classes`.
    indices : sequence of int, optional
        The library index of each grain, in pouring order (`n_particles` of them),
        instead of drawing them, e.g. one grain made for each placement
        (`synthpack.library.deform`); not with `size_classes`.

    Returns
    -------
    PourPlan

    Raises
    ------
    SynthpackInputError
        For an empty size class, a tube too narrow for the largest grain, or `indices`
        that are not `n_particles` library indices (or come with `size_classes`).
    """
    rng = generator(seed, "plan")
    low, high = parse_scale(scale)
    classes = parse_size_classes(size_classes)
    if indices is None:
        indices = _draw_indices(library, n_particles, classes, rng)
    else:
        indices = _given_indices(indices, n_particles, len(library), classes)
    quaternions = Rotation.random(n_particles, random_state=rng).as_quat(scalar_first=True)
    quaternions *= np.where(quaternions[:, :1] < 0, -1.0, 1.0)
    scales = rng.uniform(low, high, n_particles) if high > low else np.full(n_particles, low)
    extents = np.array(
        [float(np.linalg.norm(library[i].mesh.vertices, axis=1).max()) for i in range(len(library))]
    )
    radii = extents[indices] * scales
    if radii.max() * (1 + SPAWN_GAP) > tube.inner_radius:
        raise SynthpackInputError(
            f"The tube (inner radius {tube.inner_radius:g}) is too narrow for the largest "
            f"grain (bounding radius {radii.max():g} about its origin, plus a "
            f"{SPAWN_GAP:.0%} spawn gap); use a wider tube or a smaller scale."
        )
    batches = np.arange(n_particles) // batch_size
    offsets = np.empty((n_particles, 3))
    for b in range(int(batches[-1]) + 1):
        members = np.flatnonzero(batches == b)
        offsets[members] = _spawn_points(radii[members], tube, rng)
    logger.debug("Plan: %d grains in %d batches, seed %d", n_particles, batches[-1] + 1, seed)
    return PourPlan(
        indices=indices,
        quaternions=quaternions,
        scales=scales,
        batches=batches.astype(np.int64),
        spawn_offsets=offsets,
        bounding_radii=radii,
        seed=int(seed),
    )


def _positive_float(value: Any, name: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not (math.isfinite(number) and number > 0):
        raise SynthpackInputError(f"{name} must be a finite positive number, got {value!r}.")
    return number


def _draw_indices(
    library: LibraryLike,
    n: int,
    classes: list[tuple[float, float, float]] | None,
    rng: np.random.Generator,
) -> np.ndarray:
    """Library indices of `n` grains, with replacement by the library's `draw_weights`, optionally per size class."""
    weights = np.asarray(library.draw_weights, dtype=float)
    if classes is None:
        return draw(rng, weights, n)
    diameters = np.asarray(library.equivalent_diameters, dtype=float)
    counts = _largest_remainder([f for _, _, f in classes], n)
    chosen = []
    for (d_min, d_max, _), count in zip(classes, counts):
        members = np.flatnonzero((diameters >= d_min) & (diameters < d_max))
        if count and members.size == 0:
            raise SynthpackInputError(
                f"No grain of the library has an equivalent diameter in [{d_min:g}, {d_max:g}) "
                f"(the library spans {diameters.min():g} .. {diameters.max():g}); "
                "adjust size_classes."
            )
        chosen.append(draw(rng, weights, count, members) if count else members[:0])
    return rng.permutation(np.concatenate(chosen)).astype(np.int64)


def _given_indices(
    indices: Sequence[int], n: int, n_library: int, classes: list[tuple[float, float, float]] | None,
) -> np.ndarray:
    """`indices` as int64, checked: `n` of them, each a library index; not with size classes."""
    given = np.asarray(indices)
    if classes is not None:
        raise SynthpackInputError("give either indices or size_classes, not both.")
    if given.shape != (n,) or not np.issubdtype(given.dtype, np.integer) or given.min() < 0 \
            or given.max() >= n_library:
        raise SynthpackInputError(
            f"indices must be {n} whole numbers in [0, {n_library}) (a library index per grain), "
            f"got shape {given.shape} of {given.dtype}."
        )
    return given.astype(np.int64)


def _largest_remainder(fractions: Sequence[float], n: int) -> np.ndarray:
    """Integer counts summing to `n`, proportional to `fractions` (Hamilton's method)."""
    exact = np.asarray(fractions, dtype=float) * n
    counts = np.floor(exact).astype(np.int64)
    order = np.argsort(-(exact - counts), kind="stable")
    counts[order[: n - int(counts.sum())]] += 1
    return counts


def _spawn_points(radii: np.ndarray, tube: Tube, rng: np.random.Generator) -> np.ndarray:
    """``(len(radii), 3)`` spawn offsets ``(x, y, dz)`` without overlaps, by random deposition.

    Grains are placed one after another as spheres of their bounding radius (plus
    a clearance of ``SPAWN_GAP`` times the batch's largest radius): each tries
    :data:`_SPAWN_CANDIDATES` random points of the tube's disc (where its sphere
    clears the wall) and takes the one where it can sit lowest, above the pack top
    and on top of the spheres placed before it. So a batch spawns as a loose,
    random, overlap-free heap just above the pack, and falls only a short way.
    """
    gap = float(radii.max()) * SPAWN_GAP
    centres = np.empty((len(radii), 3))
    for k, radius in enumerate(radii):
        reach = max(tube.inner_radius - radius - gap, 0.0)
        # uniform points of the disc of radius `reach`
        rho = reach * np.sqrt(rng.uniform(0.0, 1.0, _SPAWN_CANDIDATES))
        angle = rng.uniform(0.0, 2 * np.pi, _SPAWN_CANDIDATES)
        xy = np.column_stack([rho * np.cos(angle), rho * np.sin(angle)])
        z = np.full(_SPAWN_CANDIDATES, radius + gap)
        if k:
            contact = radius + radii[:k] + gap  # (k,) centre distances needed
            horizontal = np.linalg.norm(xy[:, None, :] - centres[None, :k, :2], axis=2)
            lift = np.sqrt(np.maximum(contact[None, :] ** 2 - horizontal**2, 0.0))
            above = np.where(horizontal < contact[None, :], centres[None, :k, 2] + lift, -np.inf)
            z = np.maximum(z, above.max(axis=1))
        best = int(np.argmin(z))
        centres[k] = (xy[best, 0], xy[best, 1], z[best])
    return centres
