"""Shape diversity: free-form deformation of library grains (the paper's future work, its ref. 15).

A lattice free-form deformation (Sederberg and Parry, 1986) bends a grain through a
small lattice of control points over its bounding box. With ``l`` control points per
axis (Bernstein polynomials of degree ``n = l - 1``), a point of parametric position
``u`` in the box (``u`` in [0, 1]^3) moves by

    D(u) = sum_ijk B_i(u_x) B_j(u_y) B_k(u_z) delta_ijk,

where ``delta_ijk`` is the displacement of control point ``ijk`` (undisplaced control
points give the identity, by the Bernstein basis' linear precision). Displacements are
drawn uniformly in ``[-strength, strength]`` per component, in units of the box's
extent along that axis: the deformation is the same in the box's parametric frame
whatever the grain's aspect, and so is its Jacobian determinant.

Each grain of a pack is made once per placement, before the pour, as a new
`~synthpack.library.particles.Particle` in its own frame, so the physics and the render see
just another particle:

- the mesh (what the physics collides) is moved by the forward map: same faces, so it
  stays watertight;
- the clean crop and the mask (what the render draws) are resampled at the inverse map
  of every voxel of a new crop (Newton iterations: the map is near the identity),
  with :func:`scipy.ndimage.map_coordinates`;
- both are then scaled about the deformed mesh's centre of mass by the one factor that
  gives the deformed mesh the volume of the source grain's mesh (a random lattice
  changes it by a few per cent), so the grain keeps its size;
- the new crop is cut to the deformed mask's box, and the particle's local origin is
  that box's centre, as for library grains.

A draw that would fold the box over itself (the Jacobian determinant below
`MIN_JACOBIAN` somewhere in it: the mesh would intersect itself and the inverse would
not be unique) is scaled down to the largest factor with which it does not; the
factor is recorded. What is needed to redo a pack's grains (strength, lattice, each placement's
seed and applied factor) is recorded in its placements (`PackGrains.record`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

from .._shared.schema import in_range, setting
from .._shared.seeds import stream
from .core import ParticleLibrary
from .particles import Particle
from .sampling import draw

logger = logging.getLogger(__name__)

__all__ = ["DeformConfig", "LatticeFFD", "PackGrains", "deform_particle", "draw_ffd", "pack_grains", "redo_grains"]

#: The smallest Jacobian determinant a deformation may have anywhere in the grain's box.
MIN_JACOBIAN = 0.3
#: Bisection steps for the damping factor of a draw that would fold its grain (to 1/256).
_BISECTIONS = 8
#: Newton iterations of the inverse map, and the residual (fraction of the box's smallest extent)
#: a converged point must reach.
_NEWTON_STEPS = 12
_NEWTON_TOLERANCE = 1e-6
#: How far outside the box (fraction of its extent) the inverse map is sought.
_REACH = 0.1
#: The inverse map is solved on every _COARSE-th voxel per axis, and interpolated in between.
_COARSE = 2
#: Empty voxels kept around the deformed grain while its crop is resampled.
_MARGIN = 3
#: Points per axis of the grid on which a deformation's Jacobian is checked.
_CHECK_POINTS = 9


@dataclass(frozen=True)
class DeformConfig:
    """Free-form deformation of the grains: the ``grains.deform`` section of a pack config.

    ``strength: 0`` (the default) leaves the library's grains as they are: volumes,
    labels and placements are byte for byte those of a synthpack without deformation.
    """

    strength: float = setting(0.0, in_range(0.0, 0.5),
                              "free-form deformation of each placed grain: the largest control-point "
                              "displacement, as a fraction of the grain's box along each axis (0: off)")
    lattice: int = setting(3, in_range(2, 6), "control points per axis of the deformation lattice "
                                              "(2: trilinear, 3: quadratic bending, 4: cubic)")


def _bernstein(u: np.ndarray, degree: int) -> np.ndarray:
    """Bernstein basis of `degree` at `u` (shape (P,)): shape (P, degree + 1)."""
    i = np.arange(degree + 1)
    binomial = np.array([math.comb(degree, k) for k in i], dtype=float)
    return binomial * u[:, None] ** i * (1.0 - u[:, None]) ** (degree - i)


def _bernstein_derivative(u: np.ndarray, degree: int) -> np.ndarray:
    """d/du of the Bernstein basis of `degree` at `u` (shape (P,)): shape (P, degree + 1)."""
    lower = np.pad(_bernstein(u, degree - 1), ((0, 0), (1, 1)))  # B_{-1} = B_degree = 0 at degree - 1
    return degree * (lower[:, :-1] - lower[:, 1:])


@dataclass(frozen=True)
class LatticeFFD:
    """A lattice free-form deformation of a box, in the box's frame.

    Attributes
    ----------
    lo : ndarray of float64, shape (3,)
        Lower corner of the box, ``(x, y, z)``, physical units.
    extent : ndarray of float64, shape (3,)
        The box's size along ``x, y, z``, physical units (> 0).
    displacements : ndarray of float64, shape (l, l, l, 3)
        Control-point displacements ``delta[i, j, k]`` (control point ``i`` along x,
        ``j`` along y, ``k`` along z), in units of `extent` per component.
    """

    lo: np.ndarray
    extent: np.ndarray
    displacements: np.ndarray

    @property
    def degree(self) -> int:
        """Degree of the Bernstein polynomials: control points per axis minus one."""
        return self.displacements.shape[0] - 1

    def _parametric(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=float) - self.lo) / self.extent

    def _moved(self, bases: Sequence[np.ndarray]) -> np.ndarray:
        """``sum_ijk bx_i by_j bz_k delta_ijk`` for per-axis bases (3 arrays of shape (P, l)): shape (P, 3)."""
        bx, by, bz = bases
        weights = (bx[:, :, None, None] * by[:, None, :, None] * bz[:, None, None, :]).reshape(len(bx), -1)
        return weights @ self.displacements.reshape(-1, 3)

    def forward(self, points: np.ndarray) -> np.ndarray:
        """The deformed positions of `points` ((P, 3) float, ``(x, y, z)``, physical units): shape (P, 3)."""
        points = np.asarray(points, dtype=float)
        u = self._parametric(points)
        moved = self._moved([_bernstein(u[:, a], self.degree) for a in range(3)])
        return points + moved * self.extent

    def jacobian(self, points: np.ndarray) -> np.ndarray:
        """The map's Jacobian matrices ``d forward / d points`` at `points` ((P, 3)): shape (P, 3, 3)."""
        u = self._parametric(points)
        basis = [_bernstein(u[:, a], self.degree) for a in range(3)]
        slopes = [_bernstein_derivative(u[:, a], self.degree) for a in range(3)]
        parametric = np.empty((len(u), 3, 3))
        for b in range(3):  # derivative along parametric axis b
            parametric[:, :, b] = self._moved([slopes[a] if a == b else basis[a] for a in range(3)])
        # physical: d x_c / d p_b = delta_cb + extent_c * dD_c/du_b / extent_b
        return np.eye(3) + parametric * self.extent[None, :, None] / self.extent[None, None, :]

    def min_jacobian(self, points: int = _CHECK_POINTS) -> float:
        """The smallest Jacobian determinant on a ``points^3`` grid over the box (1 for the identity)."""
        axis = np.linspace(0.0, 1.0, points)
        u = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
        return float(np.linalg.det(self.jacobian(self.lo + u * self.extent)).min())

    def inverse(self, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points of the box whose deformed positions are `targets` ((P, 3)), by Newton's method.

        Outside the box the polynomial map may fold, so the inverse is sought only
        for targets whose first-order inverse ``t - D(t)`` lies in the box grown by
        `_REACH` of its extent on every side; the others are reported not converged.

        Returns
        -------
        points : ndarray of float64, shape (P, 3)
        converged : ndarray of bool, shape (P,)
            Where every component of the residual ``forward(points) - targets`` fell
            below ``1e-6`` of the box's smallest extent.
        """
        targets = np.asarray(targets, dtype=float)
        points = 2.0 * targets - self.forward(targets)  # first-order guess t - D(t)
        u = self._parametric(points)
        active = np.flatnonzero(np.all((u > -_REACH) & (u < 1.0 + _REACH), axis=1))
        tolerance = _NEWTON_TOLERANCE * float(self.extent.min())
        converged = np.zeros(len(targets), dtype=bool)
        for _ in range(_NEWTON_STEPS + 1):
            residual = self.forward(points[active]) - targets[active]
            moving = np.any(np.abs(residual) >= tolerance, axis=1)
            converged[active[~moving]] = True
            active, residual = active[moving], residual[moving]
            if not len(active):
                break
            step = np.linalg.solve(self.jacobian(points[active]), residual[:, :, None])[:, :, 0]
            points[active] -= np.clip(step, -self.extent, self.extent)
        return points, converged


def _box(particle: Particle) -> tuple[np.ndarray, np.ndarray]:
    """The particle's crop box in its local frame: lower corner and extent, ``(x, y, z)``, physical units."""
    spacing = np.asarray(particle.voxel_size, dtype=float)[::-1]
    extent = np.asarray(particle.mask.shape, dtype=float)[::-1] * spacing
    return -extent / 2.0, extent


def draw_ffd(particle: Particle, strength: float, lattice: int, seed: int) -> tuple[LatticeFFD, float]:
    """The deformation of `particle` drawn from `seed`, and the factor it was damped by.

    Control-point displacements are uniform in ``[-strength, strength]`` per component
    (in units of the box's extent), drawn from ``numpy.random.default_rng(seed)``. A
    draw whose Jacobian determinant falls below `MIN_JACOBIAN` somewhere in the box
    (it would fold the grain) is scaled down by the largest factor, found by
    bisection to 1/256, with which it does not.

    Parameters
    ----------
    particle : Particle
        The grain; the lattice covers its crop box.
    strength : float
        Largest displacement, fraction of the box's extent, >= 0.
    lattice : int
        Control points per axis, >= 2.
    seed : int
        Seed of the draw.

    Returns
    -------
    ffd : LatticeFFD
        The deformation applied (the damped one).
    factor : float
        ``1`` when the draw was kept as it is, else the damping factor in [0, 1).
    """
    lo, extent = _box(particle)
    drawn = np.random.default_rng(seed).uniform(-strength, strength, (lattice, lattice, lattice, 3))
    if LatticeFFD(lo, extent, drawn).min_jacobian() >= MIN_JACOBIAN:
        return LatticeFFD(lo, extent, drawn), 1.0
    low, high = 0.0, 1.0  # the identity (factor 0) never folds
    for _ in range(_BISECTIONS):
        middle = 0.5 * (low + high)
        if LatticeFFD(lo, extent, drawn * middle).min_jacobian() >= MIN_JACOBIAN:
            low = middle
        else:
            high = middle
    return LatticeFFD(lo, extent, drawn * low), low


def deform_particle(particle: Particle, ffd: LatticeFFD, background: float) -> Particle:
    """`particle` deformed by `ffd`, at the source grain's mesh volume, as a new particle in its own frame.

    Parameters
    ----------
    particle : Particle
        The library grain.
    ffd : LatticeFFD
        A deformation of its box (from :func:`draw_ffd`), without folds.
    background : float
        Value of the new clean crop outside the new mask: the library's background
        (its source's pore level, `~synthpack.source.SourceStatistics.pore_mean`).

    Returns
    -------
    Particle
        Same label, density and border flag. Its mesh is the forward-deformed,
        volume-rescaled mesh (the same faces, so watertight); its crop (float32) and
        mask (bool) are the source's resampled at the inverse map of every new voxel,
        cut to the new mask's box, whose centre is the new local origin. ``bbox`` keeps
        the source box's lower corner with the new crop's shape.
    """
    spacing_xyz = np.asarray(particle.voxel_size, dtype=float)[::-1]
    vertices = ffd.forward(np.asarray(particle.mesh.vertices, dtype=float))
    deformed = trimesh.Trimesh(vertices, np.asarray(particle.mesh.faces), process=False)
    centre = np.asarray(deformed.center_mass, dtype=float)
    ratio = float(particle.mesh.volume) / float(deformed.volume)
    scale = ratio ** (1.0 / 3.0)
    vertices = centre + scale * (vertices - centre)

    # a generous grid over the deformed grain, in the deformed (not yet re-centred) frame, on the
    # source crop's voxel lattice (so that no deformation resamples nothing)
    first = -(np.asarray(particle.mask.shape, dtype=float)[::-1] - 1.0) / 2.0 * spacing_xyz
    lo = first + spacing_xyz * (np.floor((vertices.min(axis=0) - first) / spacing_xyz) - _MARGIN)
    shape_xyz = np.ceil((vertices.max(axis=0) + _MARGIN * spacing_xyz - lo) / spacing_xyz).astype(int) + 1
    sources = _inverse_on_grid(ffd, lambda q: centre + (q - centre) / scale, lo, spacing_xyz, shape_xyz)
    source_shape_zyx = np.asarray(particle.mask.shape, dtype=float)
    index_zyx = (sources / spacing_xyz)[..., ::-1] + (source_shape_zyx - 1.0) / 2.0
    index_zyx[np.isnan(index_zyx)] = -10.0  # no inverse: outside the source crop, empty
    index_zyx = np.moveaxis(index_zyx, -1, 0)
    mask = ndimage.map_coordinates(particle.mask.astype(np.float32), index_zyx, order=1, mode="constant",
                                   cval=0.0) > 0.5
    mask = _largest_component(mask)
    box = ndimage.find_objects(mask.astype(np.int8))[0]
    mask = mask[box]
    tomogram = ndimage.map_coordinates(particle.tomogram, index_zyx, order=1, mode="constant",
                                       cval=background)[box]
    tomogram = np.where(mask, tomogram, background).astype(np.float32)

    # the new local origin: the centre of the new crop box
    lower_zyx = np.array([s.start for s in box], dtype=float)
    origin_xyz = lo + spacing_xyz * (lower_zyx[::-1] + (np.asarray(mask.shape, dtype=float)[::-1] - 1.0) / 2.0)
    mesh = trimesh.Trimesh(vertices - origin_xyz, np.asarray(particle.mesh.faces), process=False)
    corner = tuple(int(v) for v in particle.bbox[:3])
    bbox = corner + tuple(c + n for c, n in zip(corner, mask.shape))
    return Particle(particle.label, bbox, tomogram, mask, particle.voxel_size, particle.touches_border, mesh,
                    particle.density)


def _inverse_on_grid(
    ffd: LatticeFFD, unscale: Callable[[np.ndarray], np.ndarray], lo: np.ndarray, spacing: np.ndarray,
    shape: np.ndarray,
) -> np.ndarray:
    """Source positions of every voxel of a grid, by the inverse FFD.

    The inverse is solved (`LatticeFFD.inverse`) on every `_COARSE`-th voxel per axis
    and interpolated linearly in between: it is a smooth, near-identity map, which
    this reproduces to about 0.01 voxels at a sixth of the cost.

    Parameters
    ----------
    ffd : LatticeFFD
    unscale : callable
        Undoes the volume rescaling: deformed position -> position ``ffd`` maps to it, ((P, 3) -> (P, 3)).
    lo : ndarray, shape (3,)
        ``(x, y, z)`` of the grid's first voxel centre, physical units.
    spacing : ndarray, shape (3,)
        Voxel size along ``x, y, z``.
    shape : ndarray of int, shape (3,)
        Voxels along ``x, y, z``.

    Returns
    -------
    ndarray of float64, shape (nz, ny, nx, 3)
        ``(x, y, z)`` source positions (the source grain's local frame); NaN where no
        inverse was found (far outside the source box).
    """
    coarse = [lo[a] + spacing[a] * _COARSE * np.arange(-(-int(shape[a] - 1) // _COARSE) + 1) for a in range(3)]
    z, y, x = np.meshgrid(coarse[2], coarse[1], coarse[0], indexing="ij")
    sources, converged = ffd.inverse(unscale(np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)))
    sources[~converged] = np.nan
    sources = sources.reshape(z.shape + (3,))
    fine = np.meshgrid(*(np.arange(int(shape[a])) / _COARSE for a in (2, 1, 0)), indexing="ij")
    return np.stack([ndimage.map_coordinates(sources[..., c], fine, order=1, mode="nearest") for c in range(3)],
                    axis=-1)


def _largest_component(mask: np.ndarray) -> np.ndarray:
    """The largest 6-connected piece of `mask` (resampling may leave specks at thin spots)."""
    components, n = ndimage.label(mask)
    if n <= 1:
        return mask
    sizes = np.bincount(components.ravel())
    sizes[0] = 0
    return components == int(np.argmax(sizes))


@dataclass(frozen=True)
class PackGrains:
    """The grains of one pack: placement ``k`` pours ``particles[k]``, a deformed ``library[sources[k]]``.

    Attributes
    ----------
    particles : ParticleLibrary
        One deformed grain per placement (with the library's voxel size, statistics and source).
    sources : ndarray of int64, shape (N,)
        The library index of each placement's grain.
    record : dict
        JSON-able: ``method`` (``"lattice-ffd"``), ``strength``, ``lattice``, ``min_jacobian``, and per
        placement ``seeds`` (of :func:`draw_ffd`) and ``factors`` (the damping each draw got):
        with the library, what redoes every grain (:func:`pack_grains` of the same arguments).
    """

    particles: ParticleLibrary
    sources: np.ndarray
    record: dict


def pack_grains(library: ParticleLibrary, n_particles: int, deform: DeformConfig, seed: int) -> PackGrains | None:
    """The deformed grains of a pack, one per placement; None when ``deform.strength`` is 0.

    The source grain of each placement is drawn from `library` with replacement by
    its `~synthpack.library.core.ParticleLibrary.draw_weights` (as the pour draws
    them without deformation), then deformed with its
    own seed (:func:`draw_ffd`, :func:`deform_particle`). Every draw comes from
    the pack seed's ``"grains"`` stream (`synthpack._shared.seeds`), which no other stage
    uses, so the same seed gives the same grains.

    Parameters
    ----------
    library : ParticleLibrary
        The source grains.
    n_particles : int
        Placements of the pack.
    deform : DeformConfig
        Strength and lattice.
    seed : int
        The pack seed.

    Returns
    -------
    PackGrains or None
    """
    if deform.strength == 0:
        return None
    sequence = stream(seed, "grains")
    sources = draw(np.random.default_rng(sequence), library.draw_weights, n_particles)
    seeds = [int(s) for s in sequence.spawn(1)[0].generate_state(n_particles, np.uint32)]
    particles, factors = _deformed(library, sources, seeds, deform)
    damped = sum(f < 1 for f in factors)
    if damped:
        logger.info("%d of %d deformations would fold their grain: scaled down until they do not",
                    damped, n_particles)
    record = dict(method="lattice-ffd", strength=float(deform.strength), lattice=int(deform.lattice),
                  min_jacobian=MIN_JACOBIAN, seeds=seeds, factors=factors)
    return PackGrains(particles, sources, record)


def _deformed(
    library: ParticleLibrary, sources: Sequence[int], seeds: Sequence[int], deform: DeformConfig,
) -> tuple[ParticleLibrary, list[float]]:
    """Grain ``library[sources[k]]`` deformed with seed ``seeds[k]``, for every k; and the damping factors."""
    background = float(library.statistics.pore_mean)
    particles: list[Particle] = []
    factors: list[float] = []
    for source, grain_seed in zip(sources, seeds):
        particle = library[int(source)]
        ffd, factor = draw_ffd(particle, deform.strength, deform.lattice, int(grain_seed))
        particles.append(deform_particle(particle, ffd, background))
        factors.append(factor)
    return library.with_particles(particles), factors


def redo_grains(library: ParticleLibrary, sources: Sequence[int], record: dict) -> ParticleLibrary:
    """The deformed grains a `PackGrains.record` describes, from `library` (e.g. to render saved placements).

    Parameters
    ----------
    library : ParticleLibrary
        The library the pack was made from.
    sources : sequence of int
        The library index of each placement's grain (``Placements.indices``).
    record : dict
        The placements' ``grains`` record (`PackGrains.record`).

    Returns
    -------
    ParticleLibrary
        One grain per placement, identical to the pack's.
    """
    deform = DeformConfig(strength=record["strength"], lattice=record["lattice"])
    return _deformed(library, sources, record["seeds"], deform)[0]
