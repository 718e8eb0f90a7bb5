"""Quality checks of a finished pour, computed from the placed meshes (engine-independent).

* **Grains outside the tube**: a grain is outside if any of its vertices lies more
  than `tolerance` beyond the inner wall (radially) or below the floor. Must be 0.
  Grains reaching above the rim are counted separately (the tube was overfilled).
* **Wall penetration**: the largest distance any vertex reaches into the wall or
  floor (exact for the meshes: the tube is analytic).
* **Grain-grain penetration**: the largest penetration depth between the CONVEX
  HULLS of the placed meshes (full hulls, not the simplified collision hulls),
  from pybullet's GJK/EPA contact query at the final poses (with a tiny margin,
  taken off again). For
  convex grains this is the true depth; for concave grains it is an upper bound.
* **Overlap fraction**: the fraction of the solid Monte-Carlo sample points (below)
  that lie inside two or more grains' meshes: a mesh-exact measure of overlap.
* **Packing fraction of the bulk**: the solid volume fraction inside a sub-cylinder
  one median grain diameter away from the wall (two for the pour of an interior crop:
  `wall_margin`) and the floor and two diameters below the pack's top (the highest grain point), or in the
  pour of an interior crop only the crop's footprint in it (`crop`: the box the pack will show, which lies
  in the middle of the tube, denser than the cylinder's rim), estimated by sampling
  `n_samples` uniform random points in it and testing each against every nearby
  grain's convex hull (a cheap half-space test) and, if inside it, against the
  grain's mesh with the generalized winding number (robust for watertight
  meshes; standard error about ``sqrt(f (1 - f) / n_samples)``, ~0.004 at 20,000).
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from .._shared.seeds import generator
from .container import Tube, crop_half_sides

logger = logging.getLogger(__name__)

__all__ = ["BULK_FLOOR_MARGIN", "BULK_TOP_MARGIN", "PourChecks", "bulk_shortfall", "compute_checks",
           "solid_fraction_of", "winding_number"]

#: The bulk region starts this many grain diameters above the floor ...
BULK_FLOOR_MARGIN = 1.0
#: ... and ends this many below the pack's top: a pack needs to be more than their sum (3) deep for one.
BULK_TOP_MARGIN = 2.0

# Collision margin (in grain diameters) of the penetration query; subtracted twice
# from the reported depth. Bullet's EPA is wrong with a zero margin (measured: two
# cubes overlapping by 0.3 gave 0.173 = 0.3 / sqrt(3)), exact with a small one.
_QUERY_MARGIN = 1e-3
# Growth of a grain's box (a share of its largest side) when picking the Monte-Carlo points to test.
_BOX_PAD = 1e-9


@dataclass
class PourChecks:
    """Checks of one pour; lengths in physical units, and in voxels where named so.

    Attributes
    ----------
    n_outside : int
        Grains reaching more than `tolerance` into the wall or floor (must be 0).
    n_above_rim : int
        Grains reaching above the tube's rim.
    tolerance : float
        Tolerance used for `n_outside`, physical units.
    max_wall_penetration, max_wall_penetration_voxels : float
        Deepest reach of a grain into the wall or floor (0 if none).
    max_grain_penetration, max_grain_penetration_voxels : float
        Largest penetration depth between two grains' convex hulls (0 if none).
    overlap_fraction : float
        Fraction of solid sample points inside two or more grains.
    packing_fraction : float
        Solid fraction of the bulk region (NaN if the pack is too shallow for one).
    packing_region : dict
        ``radius``, ``z_min``, ``z_max`` of the bulk sub-cylinder, ``n_samples``; for the pour of
        an interior crop also ``crop_half_sides``, the ``(Y, X)`` half sides of the crop's footprint
        centred on the axis, measured instead of the whole cylinder.
    fill_height : float
        Highest point of any grain (the pack top).
    steps_per_batch : list of int
        Engine steps per batch.
    settled_per_batch : list of bool
        Whether each batch met the settle criteria (False: hit the step cap).
    seconds : float
        Wall-clock time of the engine run. Not saved (:meth:`to_dict` leaves it out, so the same
        pour saves the same bytes): the pack's manifest keeps it, as ``timings.pour_engine``.
    target_packing_fraction : float or None
        The packing fraction the pour aimed at (:mod:`synthpack.physics.compaction`);
        None for a free pour.
    target_reached : bool or None
        Whether `packing_fraction` is within
        :data:`~synthpack.physics.compaction.TARGET_TOLERANCE` of the target; None
        for a free pour or a pack without a bulk region.
    compaction : dict or None
        The knob of each batch and the bulk layers measured while pouring.
    """

    n_outside: int
    n_above_rim: int
    tolerance: float
    max_wall_penetration: float
    max_wall_penetration_voxels: float
    max_grain_penetration: float
    max_grain_penetration_voxels: float
    overlap_fraction: float
    packing_fraction: float
    packing_region: dict[str, float]
    fill_height: float
    steps_per_batch: list[int] = field(default_factory=list)
    settled_per_batch: list[bool] = field(default_factory=list)
    seconds: float = field(default=0.0, compare=False)  # wall-clock: not part of the result
    target_packing_fraction: float | None = None
    target_reached: bool | None = None
    compaction: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dictionary (NaN becomes None), without the wall-clock `seconds`."""
        data = asdict(self)
        data.pop("seconds")
        return {k: (None if isinstance(v, float) and np.isnan(v) else v) for k, v in data.items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PourChecks:
        """Inverse of :meth:`to_dict` (`seconds` 0 unless given, as older placements files do)."""
        values = dict(data)
        if values.get("packing_fraction") is None:
            values["packing_fraction"] = float("nan")
        return cls(**values)

    def packing_text(self) -> str:
        """The packing fraction and its target's verdict, for people: ``"0.581 (target 0.580: reached)"``."""
        text = (f"n/a (pack shallower than ~{BULK_FLOOR_MARGIN + BULK_TOP_MARGIN:g} grain diameters)"
                if np.isnan(self.packing_fraction)
                else f"{self.packing_fraction:.3f}")
        if self.target_packing_fraction is None:
            return text
        verdict = {True: "reached", False: "NOT reached", None: "not judged, no bulk"}[self.target_reached]
        return f"{text} (target {self.target_packing_fraction:.3f}: {verdict})"

    def summary(self) -> str:
        """One line for logs."""
        return (
            f"outside={self.n_outside} above_rim={self.n_above_rim} "
            f"packing={self.packing_fraction:.3f} "
            f"max_penetration grain={self.max_grain_penetration_voxels:.2f} vx "
            f"wall={self.max_wall_penetration_voxels:.2f} vx overlap={self.overlap_fraction:.4f} "
            f"steps={sum(self.steps_per_batch)} unsettled={self.settled_per_batch.count(False)}"
            + ("" if self.target_packing_fraction is None else
               f" target={self.target_packing_fraction:.3f} reached={self.target_reached}")
        )


def compute_checks(
    meshes: Sequence[tuple[np.ndarray, np.ndarray]],
    indices: np.ndarray,
    positions: np.ndarray,
    quaternions: np.ndarray,
    scales: np.ndarray,
    tube: Tube,
    *,
    voxel_size: float,
    length_scale: float,
    steps_per_batch: Sequence[int] = (),
    settled_per_batch: Sequence[bool] = (),
    seconds: float = 0.0,
    n_samples: int = 20_000,
    seed: int = 0,
    wall_margin: float = 1.0,
    crop: tuple[float, float] | None = None,
) -> PourChecks:
    """Check a pour's final state.

    Parameters
    ----------
    meshes : sequence of (vertices (V, 3) float, faces (F, 3) int)
        Local-frame meshes of the library, physical units, indexed by `indices`.
    indices : numpy.ndarray
        (N,) library index of each placed grain.
    positions : numpy.ndarray
        (N, 3) world position of each grain's local origin, physical units.
    quaternions : numpy.ndarray
        (N, 4) unit quaternions (w, x, y, z), local -> world.
    scales : numpy.ndarray
        (N,) scale factors.
    tube : Tube
        The container, physical units.
    voxel_size : float
        Length of one voxel, physical units: penetrations are also given in voxels
        and `n_outside` tolerates half a voxel.
    length_scale : float
        A typical grain diameter, physical units: sets the bulk region's margins.
    steps_per_batch, settled_per_batch, seconds
        Engine statistics, stored as given.
    n_samples : int
        Monte-Carlo points for the packing and overlap fractions.
    seed : int
        Seed of the sample points.
    wall_margin : float
        Distance of the bulk region from the wall, in `length_scale` (1; 2 for the pour of
        an interior crop, `~synthpack.physics.container.CROP_WALL_MARGIN`).
    crop : (float, float), optional
        For the pour of an interior crop: the ``(Y, X)`` extent the crop aims at
        (`~synthpack.physics.container.crop_extent`), physical units; the packing fraction is
        measured in its footprint (`~synthpack.physics.container.crop_half_sides`), where the
        pack is shown. None: the whole bulk cylinder.

    Returns
    -------
    PourChecks
    """
    rotations = Rotation.from_quat(np.asarray(quaternions), scalar_first=True)
    world = [
        rotations[k].apply(meshes[i][0] * scales[k]) + positions[k] for k, i in enumerate(indices)
    ]
    tolerance = 0.5 * voxel_size
    radial_excess = np.array([np.hypot(w[:, 0], w[:, 1]).max() - tube.inner_radius for w in world])
    below_floor = np.array([-w[:, 2].min() for w in world])
    tops = np.array([w[:, 2].max() for w in world])
    n_outside = int(np.count_nonzero((radial_excess > tolerance) | (below_floor > tolerance)))
    wall_pen = float(max(0.0, radial_excess.max(), below_floor.max()))
    fill = float(tops.max())
    grain_pen = _max_hull_penetration(world, length_scale)
    packing, overlap, region = _packing(
        meshes, indices, positions, rotations, scales, world, tube, fill, length_scale,
        n_samples, seed, wall_margin, crop,
    )
    checks = PourChecks(
        n_outside=n_outside,
        n_above_rim=int(np.count_nonzero(tops > tube.height)),
        tolerance=tolerance,
        max_wall_penetration=wall_pen,
        max_wall_penetration_voxels=wall_pen / voxel_size,
        max_grain_penetration=grain_pen,
        max_grain_penetration_voxels=grain_pen / voxel_size,
        overlap_fraction=overlap,
        packing_fraction=packing,
        packing_region=region,
        fill_height=fill,
        steps_per_batch=[int(s) for s in steps_per_batch],
        settled_per_batch=[bool(s) for s in settled_per_batch],
        seconds=float(seconds),
    )
    logger.debug("Pour checks: %s", checks.summary())
    if checks.n_outside:
        logger.warning("%d grains ended outside the tube.", checks.n_outside)
    if checks.n_above_rim:
        logger.warning("%d grains reach above the tube's rim: use a taller tube.",
                       checks.n_above_rim)
    return checks


def bulk_shortfall(region: dict[str, float], n_grains: int | None) -> str:
    """Why a pour has no bulk region, and what gives one: a phrase for a warning or an error.

    The bulk is the region of :attr:`PourChecks.packing_region`: `BULK_FLOOR_MARGIN` grain
    diameters above the floor to `BULK_TOP_MARGIN` below the pack's top, so a pack needs
    to be more than their sum deep. In a given tube a pack's depth grows about in
    proportion to its grains: the estimate is the grains of a pack one diameter deeper
    than that (a bulk one diameter deep), and always more than `n_grains`.

    Parameters
    ----------
    region : dict
        ``radius``, ``z_min``, ``z_max`` of the pour's bulk sub-cylinder
        (:attr:`PourChecks.packing_region`), physical units.
    n_grains : int or None
        The grains poured; None (or 0): unknown, the phrase asks for "more grains".

    Returns
    -------
    str
        One short phrase, e.g. ``"2.3 diameters deep, a bulk needs > 3; pour ~35: --n-particles 35
        (pour.n_particles)"`` (grain diameters; the CLI flag, then the config key).
    """
    ask = "--n-particles (pour.n_particles)"
    if region["radius"] <= 0:
        return "the tube is too narrow for a bulk away from its wall: widen it, --tube-radius (pour.tube_radius)"
    diameter = region["z_min"] / BULK_FLOOR_MARGIN
    if diameter <= 0:
        return f"pour more grains: {ask}"
    least = BULK_FLOOR_MARGIN + BULK_TOP_MARGIN
    depth = (region["z_max"] + BULK_TOP_MARGIN * diameter) / diameter  # the pack's top, in grain diameters
    shallow = (f"{depth:.1f} diameters deep, a bulk needs > {least:g}" if depth <= least
               else f"bulk {depth - least:.2f} diameters deep, too thin")
    if not n_grains or depth <= 0:
        return f"{shallow}; pour more grains: {ask}"
    needed = max(math.ceil(n_grains * (least + 1) / depth), n_grains + 1)
    return f"{shallow}; pour ~{needed}: --n-particles {needed} (pour.n_particles)"


def winding_number(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Generalized winding number of a closed triangle mesh at `points`.

    Parameters
    ----------
    points : numpy.ndarray
        (M, 3) query points.
    vertices, faces : numpy.ndarray
        (V, 3) float and (F, 3) int triangle mesh with outward normals.

    Returns
    -------
    numpy.ndarray
        (M,) float: ~1 inside a watertight mesh, ~0 outside (Van Oosterom-Strackee
        solid angles summed over triangles, divided by 4 pi).
    """
    out = np.empty(len(points))
    tri = vertices[faces]  # (F, 3, 3)
    chunk = max(1, 200_000 // max(len(faces), 1))
    for start in range(0, len(points), chunk):
        d = tri[None, :, :, :] - points[start:start + chunk, None, None, :]  # (m, F, 3, 3)
        a, b, c = d[:, :, 0], d[:, :, 1], d[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("mfi,mfi->mf", a, np.cross(b, c))
        div = (la * lb * lc + np.einsum("mfi,mfi->mf", a, b) * lc
               + np.einsum("mfi,mfi->mf", a, c) * lb + np.einsum("mfi,mfi->mf", b, c) * la)
        out[start:start + chunk] = np.arctan2(det, div).sum(axis=1) / (2 * np.pi)
    return out


def _in_box(points: np.ndarray, by_x: np.ndarray, sorted_x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Indices (ascending, int64) of the `points` (n, 3) in the box ``[lo, hi]`` grown by `_BOX_PAD` of its size.

    `by_x` orders the points by x and `sorted_x` holds their x in that order, so only the slab of the
    box's x range is read. A grain's convex hull lies in the box of its vertices: every point
    inside it is among these (the pad keeps the points the rounding of the hull test could count).
    """
    pad = _BOX_PAD * float((hi - lo).max())
    lo, hi = lo - pad, hi + pad
    slab = by_x[np.searchsorted(sorted_x, lo[0], side="left"):np.searchsorted(sorted_x, hi[0], side="right")]
    y, z = points[slab, 1], points[slab, 2]
    return np.sort(slab[(y >= lo[1]) & (y <= hi[1]) & (z >= lo[2]) & (z <= hi[2])])


def _max_hull_penetration(world: list[np.ndarray], length_scale: float) -> float:
    """Largest penetration depth between the convex hulls of the placed grains."""
    from ._bullet import Client

    with Client() as client:
        for vertices in world:
            hull = vertices[ConvexHull(vertices).vertices] / length_scale
            shape = client.createCollisionShape(client.GEOM_MESH, vertices=hull.tolist())
            body = client.createMultiBody(1.0, shape, useMaximalCoordinates=True)
            client.changeDynamics(body, -1, collisionMargin=_QUERY_MARGIN)
        client.performCollisionDetection()
        contacts = client.getContactPoints()
        depth = max((-c[8] - 2 * _QUERY_MARGIN for c in contacts), default=0.0)
    return max(depth, 0.0) * length_scale


def _packing(
    meshes: Sequence[tuple[np.ndarray, np.ndarray]],
    indices: np.ndarray,
    positions: np.ndarray,
    rotations: Rotation,
    scales: np.ndarray,
    world: list[np.ndarray],
    tube: Tube,
    fill: float,
    margin: float,
    n_samples: int,
    seed: int,
    wall_margin: float,
    crop: tuple[float, float] | None,
) -> tuple[float, float, dict]:
    """(packing fraction of the bulk, overlap fraction, region) by Monte-Carlo sampling."""
    radius = tube.inner_radius - wall_margin * margin
    z_min, z_max = BULK_FLOOR_MARGIN * margin, fill - BULK_TOP_MARGIN * margin
    region: dict = {"radius": radius, "z_min": z_min, "z_max": z_max, "n_samples": n_samples}
    half = None if crop is None or radius <= 0 else crop_half_sides(radius, crop)
    if half is not None:
        region["crop_half_sides"] = [float(v) for v in half]
    if radius <= 0 or z_max <= z_min:
        logger.debug("The pack is too shallow or narrow for a bulk region: no packing fraction.")
        return float("nan"), 0.0, region
    hulls = {i: ConvexHull(meshes[i][0]).equations for i in np.unique(indices)}
    grains = [(*meshes[i], hulls[i], positions[k], rotations[k], scales[k], world[k], 1.0)
              for k, i in enumerate(indices)]
    _, hits = _hits(grains, radius, z_min, z_max, n_samples, generator(seed, "checks"), n_exact=n_samples,
                    half_sides=half)
    solid = int(np.count_nonzero(hits))
    overlap = float(np.count_nonzero(hits > 1) / solid) if solid else 0.0
    return solid / n_samples, overlap, region


def solid_fraction_of(
    grains: Sequence[tuple], radius: float, z_min: float, z_max: float, n_samples: int, rng: np.random.Generator,
    *, n_exact: int | None = None, half_sides: Sequence[float] | None = None,
) -> float:
    """Solid fraction of placed grains in the cylinder ``r < radius, z_min < z < z_max`` (Monte Carlo), or in
    the box of `half_sides` within it.

    Parameters
    ----------
    grains : sequence of tuple
        Per grain ``(vertices (V, 3), faces (F, 3), hull_equations (H, 4), position (3,),
        rotation (scipy Rotation), scale, world_vertices (V, 3), convexity)``: its
        local-frame mesh, the half-spaces of the mesh's convex hull
        (``scipy.spatial.ConvexHull.equations``), its pose (world = rotation(scale *
        local) + position), its world vertices and its mesh volume over its hull's.
    radius, z_min, z_max : float
        The cylinder about the z axis, in the units of the poses.
    n_samples : int
        Uniform random points in the cylinder (standard error ~ sqrt(f (1 - f) / n_samples)).
    rng : numpy.random.Generator
        Source of the points.
    n_exact : int, optional
        How many of the points are tested against the meshes (generalized winding number, the
        costly test); None: all of them, the fraction of the points inside a mesh. Fewer: a point
        inside a grain's hull counts as ``convexity`` of a hit (cheap), and the first `n_exact`
        points' mean difference between the exact test and that count corrects the estimate (a
        control variate: unbiased where hulls overlap, as in a pour whose shells shrink, and where
        other hulls fill a grain's concavities, at about `n_exact` / `n_samples` of the cost; the
        correction's standard error is about ``0.4 sqrt(f / n_exact)``).
    half_sides : (float, float), optional
        ``(Y, X)``: measure in the box ``|y| < half_sides[0], |x| < half_sides[1]``,
        ``z_min < z < z_max`` instead (an interior crop's footprint, within `radius`).

    Returns
    -------
    float
        The fraction of the points inside a grain's mesh (estimated as above with `n_exact`).
    """
    n_exact = n_samples if n_exact is None else min(max(int(n_exact), 0), n_samples)
    cheap, exact = _hits(grains, radius, z_min, z_max, n_samples, rng, n_exact=n_exact, half_sides=half_sides)
    if n_exact == n_samples:
        return float(np.count_nonzero(exact) / n_samples)
    correction = (np.count_nonzero(exact) - cheap[:n_exact].sum()) / n_exact if n_exact else 0.0
    return float(cheap.sum() / n_samples + correction)


def _hits(
    grains: Sequence[tuple], radius: float, z_min: float, z_max: float, n_samples: int, rng: np.random.Generator,
    *, n_exact: int, half_sides: Sequence[float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """How many grains hold each of `n_samples` uniform points of the cylinder (or of the box of ``(Y, X)``
    `half_sides` in it): the sum of the convexities of the hulls that hold it, (n_samples,) float64, and for the
    first `n_exact` points how many meshes do, (n_exact,) int32.

    Each point is tested against every nearby grain's convex hull (a cheap half-space
    test) and, if inside it and among the first `n_exact`, against the grain's mesh with the
    generalized winding number.
    """
    if half_sides is None:
        rho = radius * np.sqrt(rng.uniform(0, 1, n_samples))
        angle = rng.uniform(0, 2 * np.pi, n_samples)
        lateral = (rho * np.cos(angle), rho * np.sin(angle))
    else:
        lateral = (rng.uniform(-half_sides[1], half_sides[1], n_samples),  # x, then y
                   rng.uniform(-half_sides[0], half_sides[0], n_samples))
    points = np.column_stack([*lateral, rng.uniform(z_min, z_max, n_samples)])
    by_x = np.argsort(points[:, 0], kind="stable")
    sorted_x = points[by_x, 0]
    cheap = np.zeros(n_samples)
    exact = np.zeros(n_exact, dtype=np.int32)
    for vertices, faces, hull, position, rotation, scale, world, convexity in grains:
        lo, hi = world.min(axis=0), world.max(axis=0)
        if hi[2] < z_min or lo[2] > z_max:
            continue
        near = _in_box(points, by_x, sorted_x, lo, hi)
        if near.size == 0:
            continue
        local = rotation.inv().apply(points[near] - position) / scale
        in_hull = (local @ hull[:, :3].T + hull[:, 3]).max(axis=1) <= 0
        cheap[near[in_hull]] += convexity
        tested = in_hull & (near < n_exact)
        if tested.any():  # the mesh's triangles only for a grain that holds a point tested exactly
            near, local = near[tested], local[tested]
            exact[near[winding_number(local, vertices, faces) > 0.5]] += 1
    return cheap, exact
