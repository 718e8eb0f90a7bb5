"""Pouring grains into a virtual tube: batched, locked rigid-body simulation (paper 3.3).

:func:`pour` checks its input, draws a pour plan from one seed (:mod:`.plan`),
converts it to simulation units, runs an engine batch by batch (each batch falls,
settles and is locked before the next enters), converts the poses back to physical
units, checks the result (:mod:`.checks`) and returns :class:`Placements`.

Containment is guaranteed: a pour that leaves a grain outside the tube is run again
with twice the solver substeps; if one is still outside, or any grain reaches above
the rim, :class:`~synthpack.errors.ContainmentError` is raised instead of returning
a pack with grains outside.

Simulation units: 1 length unit = the library's median equivalent diameter times the
pour's reference scale (the geometric mean of its scale range), so grains are ~1 unit
across at any scale and a pour of grains scaled by 2 in a tube twice as wide runs the
same simulation as the unscaled one (gravity 9.81 units/s^2); 1 mass unit = the
library's median grain mass times the reference scale cubed. The engines are listed in :mod:`.registry`: ``"pybullet"`` (default,
:mod:`.pybullet_engine`) and ``"blender"`` (:mod:`.blender_engine`, bpy in a separate
interpreter, as in the paper); :mod:`.engine` is their common interface.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from typing import Any, NamedTuple

import numpy as np

from .._shared.console import progress_bar
from .._shared.text import sig
from .._shared.budget import check_pour
from ..errors import ContainmentError, SynthpackInputError
from .checks import PourChecks, compute_checks
from .compaction import PackingController, report_target, resolve_target
from .config import PourConfig
from .container import Tube
from .driver import EngineResult, LockCallback
from .engine import Engine
from .scene import Body, EngineConfig, Material, Scene, SettleCriteria, TubeSpec
from .placements import Placements
from .plan import PourPlan, make_plan, parse_scale
from .registry import get_engine
from .shells import bare_fraction, bare_grains, resolve_coordination

logger = logging.getLogger(__name__)


#: Runs of a pour before it gives up on containment: the first, then one with
#: twice the solver substeps.
CONTAINMENT_ATTEMPTS = 2


def pour(
    library: Any,
    config: PourConfig,
    seed: int,
    *,
    container: Tube | None = None,
    settle: SettleCriteria | None = None,
    size_classes: Sequence[Sequence[float]] | None = None,
    indices: Sequence[int] | None = None,
    progress: bool = True,
    wall_margin: float = 1.0,
    crop: tuple[float, float] | None = None,
    on_lock: Callable[[LockedGrains], None] | None = None,
) -> Placements:
    """Pour ``config.n_particles`` grains of `library` into a tube, ``config.batch_size`` at a time.

    ``n_particles: auto`` pours :data:`~synthpack.physics.config.DEFAULT_GRAINS`, as into a tube
    (:meth:`PourConfig.grains`); `synthpack.pipeline.generate` resolves it for an interior crop.

    Parameters
    ----------
    library : ParticleLibrary
        The grains: meshes in the local frame (physical units), masses
        (density x volume, paper eq. 1), centres of mass.
    config : PourConfig
        The pour's settings, the ``pour`` section of a pack config: count, batch size,
        engine and its ``engine_options`` (recorded in ``Placements.parameters``), grain
        scale, tube (:meth:`PourConfig.tube`), material and ``target_solid_fraction``, the
        bulk packing fraction to reach, batch by batch, by compaction or spaced collision
        shells (:mod:`synthpack.physics.compaction`); ``"source"`` is the source scan's
        (``library.statistics.solid_fraction``), which an engine without compaction ignores
        (a free pour). The reached value is in the checks (``target_reached`` False, and a
        warning, when it is more than :data:`~synthpack.physics.compaction.TARGET_TOLERANCE` away).
        ``target_coordination``, the mean contacts per grain a spaced pour aims at by leaving
        some grains bare (:mod:`synthpack.physics.shells`; ``"source"``:
        ``library.statistics.coordination``), applies to a pour with a target.
    seed : int
        Seed of every random choice (grains, orientations, scales, spawn points).
    container : Tube, optional
        The tube, physical units, instead of the one `config` sizes (:meth:`PourConfig.tube`).
    settle : SettleCriteria, optional
        Time step and settle detection; default ``SettleCriteria()``.
    size_classes : sequence of (d_min, d_max, fraction), optional
        Target size distribution by number fraction over equivalent-diameter
        classes (physical units), as by sifting.
    indices : sequence of int, optional
        The library index of each grain, in pouring order, instead of drawing
        them (see :func:`~synthpack.physics.plan.make_plan`).
    progress : bool
        Show a progress bar over batches.
    wall_margin : float
        Distance of the bulk region that the checks and the compaction measure from the
        tube wall, in median grain diameters: 1, or
        :data:`~synthpack.physics.container.CROP_WALL_MARGIN` for the pour of an interior
        crop (``reconstruct.view: interior``), whose crop lies in that region.
    crop : (float, float), optional
        For the pour of an interior crop: the ``(Y, X)`` extent it aims at
        (`~synthpack.physics.container.crop_extent`), physical units. The compaction and the
        checks then measure the crop's footprint in the bulk cylinder, the part of the pack that
        will be shown (the middle of the tube, denser than the cylinder's rim), rather than the
        whole cylinder. None: the cylinder.
    on_lock : callable, optional
        ``on_lock(grains)`` with the `LockedGrains` of each batch as it is locked (physical
        units, as the placements will hold them), e.g. to render them while the pour goes
        on. A pour run again for containment locks its batches again, from batch 0.

    Returns
    -------
    Placements
        Final poses in physical units, the tube, the parameters and the checks.

    Raises
    ------
    SynthpackInputError
        For a `config` that is not a PourConfig, a bad count, batch size, seed, settle
        criterion, scale, size class, tube or indices, or an engine that cannot run here.
    ContainmentError
        When grains end outside the tube even on the retry with twice the substeps,
        or above its rim (never a pack with grains outside).
    """
    if not isinstance(config, PourConfig):
        raise SynthpackInputError(f"config must be a PourConfig, got {type(config).__name__}: "
                                  "e.g. pour(library, PourConfig(n_particles=150, batch_size=50), seed=0).")
    n_particles, batch_size, seed = _check_request(library, config.grains(library), config.batch_size, seed)
    chosen = get_engine(config.engine)
    options = chosen.options(config.engine_options)
    material = config.material()
    settle = SettleCriteria() if settle is None else settle
    chosen.check(material, settle, options)
    target = resolve_target(config.target_solid_fraction, library, chosen)
    coordination = None if target is None else resolve_coordination(config.target_coordination, library)
    chosen.check_available()
    tube = config.tube(library) if container is None else container
    if not isinstance(tube, Tube):
        raise SynthpackInputError(f"container must be a Tube, got {type(tube).__name__}.")
    logger.info("Tube for %d grains: inner radius %s, height %s", n_particles, sig(tube.inner_radius), sig(tube.height))
    check_pour_size(library, config, tube)
    reference_scale = _reference_scale(config.scale)
    length = _length_scale(library, reference_scale)

    plan = make_plan(library, n_particles, batch_size, tube, seed=seed, scale=config.scale,
                     size_classes=size_classes, indices=indices)
    mass_unit = float(np.median([library[i].mass for i in range(len(library))])) * reference_scale**3
    bodies = _bodies(library, plan, length, mass_unit)
    spec = tube.spec(length)
    logger.info("Pouring %d grains in %d batches with %s (seed %d)%s",
                n_particles, plan.n_batches, chosen.name, seed,
                "" if target is None else f", to a packing fraction of {target:.3f}")
    bare = bare_grains(plan.batches, bare_fraction(coordination), seed)
    for attempt in range(1, CONTAINMENT_ATTEMPTS + 1):
        controller = None if target is None else PackingController(
            target, material.friction, [(b.vertices, b.faces) for b in bodies], spec.inner_radius,
            wall_margin=wall_margin, seed=seed, bare=bare, shrinks=chosen.shrinks_shells,
            crop=None if crop is None else (float(crop[0]) / length, float(crop[1]) / length))
        result, seconds = _run(chosen, bodies, spec, material, settle, options, plan.n_batches, progress,
                               controller, None if on_lock is None else _locked_grains(on_lock, plan, length))
        positions = np.asarray(result.positions, dtype=float) * length
        checks = report_target(_checks(library, plan, positions, result, tube, length, seconds, seed, wall_margin,
                                       crop), target, controller)
        if checks.n_outside == 0 or attempt == CONTAINMENT_ATTEMPTS:
            break
        logger.warning("%d grains ended outside the tube; pouring again with %d substeps per step.",
                       checks.n_outside, 2 * settle.substeps)
        settle = replace(settle, substeps=2 * settle.substeps)
    _check_containment(checks, tube)
    parameters = {
        "n_particles": n_particles,
        "batch_size": batch_size,
        "scale": list(parse_scale(config.scale)),
        "size_classes": [list(map(float, c)) for c in size_classes] if size_classes else None,
        "material": asdict(material),
        "settle": asdict(settle),
        "length_scale": length,
        "mass_unit": mass_unit,
        "target_solid_fraction": target,
        "target_coordination": coordination,
        "engine_options": {name: getattr(options, name) for name in config.engine_options},
    }
    return _placements(library, plan, positions, result, tube, chosen.name, seed, parameters, checks)


def _check_containment(checks: PourChecks, tube: Tube) -> None:
    """Raise ContainmentError for grains outside the tube or above its rim."""
    if checks.n_outside:
        raise ContainmentError(
            f"{checks.n_outside} grains ended outside the tube (up to "
            f"{checks.max_wall_penetration_voxels:.2f} voxels into the wall or floor) even with "
            "twice the solver substeps; use a smaller pour.scale or a smaller time step."
        )
    if checks.n_above_rim:
        raise ContainmentError(
            f"{checks.n_above_rim} grains reach above the tube's rim (height {tube.height:g}, pack top "
            f"{checks.fill_height:g}); give a taller pour.tube_height or pour fewer grains."
        )


def _check_request(library: Any, n_particles: Any, batch_size: Any, seed: Any) -> tuple[int, int, int]:
    """The counts and the seed as ints; SynthpackInputError for bad ones or an empty library."""
    n_particles = _count(n_particles, "n_particles")
    batch_size = _count(batch_size, "batch_size")
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SynthpackInputError(f"seed must be a whole number >= 0, got {seed!r}.")
    if len(library) == 0:
        raise SynthpackInputError(
            "The particle library is empty; build it from a labelled scan with grains in it."
        )
    return n_particles, batch_size, int(seed)


def check_pour_size(library: Any, config: PourConfig, tube: Tube) -> None:
    """Refuse up front a pour too long or too large for this machine (:func:`synthpack._shared.budget.check_pour`).

    Parameters
    ----------
    library : ParticleLibrary
        The grains (their median diameter sets the simulation unit).
    config : PourConfig
        The pour (its count, :meth:`PourConfig.grains` for the tube, and grain scale).
    tube : Tube
        The container, physical units (:meth:`PourConfig.tube`).

    Raises
    ------
    SynthpackInputError
        With the estimate (hours or GiB) and the setting to change.
    """
    check_pour(config.grains(library), tube.inner_radius / _length_scale(library, _reference_scale(config.scale)))


def _reference_scale(scale: float | Sequence[float]) -> float:
    """The geometric mean of the scale range: grains stay ~1 simulation unit across at any scale."""
    low, high = parse_scale(scale)
    return float(np.sqrt(low * high))


def _length_scale(library: Any, reference_scale: float) -> float:
    """The simulation length unit, physical units: the median grain diameter at `reference_scale`."""
    return float(np.median(np.asarray(library.equivalent_diameters, dtype=float))) * reference_scale


def _count(value: Any, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise SynthpackInputError(f"{name} must be a whole number >= 1, got {value!r}.")
    return int(value)


class LockedGrains(NamedTuple):
    """The grains of one batch as it is locked (``pour``'s `on_lock`): what their placements will hold.

    Attributes
    ----------
    batch : int
        The batch's number (0 for the first batch of a pour, or of its run again for containment).
    members : ndarray of int, shape (B,)
        The placements (pouring order).
    indices : ndarray of int, shape (B,)
        Their library grains (``Placements.indices``).
    positions : ndarray of float, shape (B, 3)
        World ``(x, y, z)`` of their local origins, physical units.
    quaternions : ndarray of float, shape (B, 4)
        Their rotations, ``(w, x, y, z)``.
    scales : ndarray of float, shape (B,)
        Their scale factors.
    """

    batch: int
    members: np.ndarray
    indices: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    scales: np.ndarray


def _locked_grains(on_lock: Callable[[LockedGrains], None], plan: PourPlan, length: float) -> LockCallback:
    """The engine's `~.driver.LockCallback` that hands `on_lock` each locked batch in physical units."""
    def locked(batch: int, members: np.ndarray, positions: np.ndarray, quaternions: np.ndarray) -> None:
        members = np.asarray(members)
        on_lock(LockedGrains(batch, members, np.asarray(plan.indices)[members],
                             np.asarray(positions, dtype=float) * length, np.asarray(quaternions),
                             np.asarray(plan.scales)[members]))
    return locked


def _run(
    engine: Engine, bodies: list[Body], tube: TubeSpec, material: Material, settle: SettleCriteria,
    options: EngineConfig, n_batches: int, progress: bool, compaction: PackingController | None,
    locked: LockCallback | None = None,
) -> tuple[EngineResult, float]:
    """The engine's result and its wall-clock time in seconds, with a progress bar over batches."""
    bar = progress_bar(total=n_batches, desc="pouring", unit="batch", disable=not progress)
    start = time.perf_counter()
    try:
        result = engine.simulate(Scene(bodies, tube, material, settle, options),
                                 progress=lambda done, total: bar.update(1), compaction=compaction,
                                 locked_batch=locked)
    finally:
        bar.close()
    return result, time.perf_counter() - start


def _checks(
    library: Any, plan: PourPlan, positions: np.ndarray, result: EngineResult, tube: Tube,
    length: float, seconds: float, seed: int, wall_margin: float, crop: tuple[float, float] | None,
) -> PourChecks:
    """The checks of the finished pour (:func:`~synthpack.physics.checks.compute_checks`)."""
    meshes = [(np.asarray(library[i].mesh.vertices, dtype=float), np.asarray(library[i].mesh.faces))
              for i in range(len(library))]
    return compute_checks(
        meshes, plan.indices, positions, result.quaternions, plan.scales, tube,
        voxel_size=float(min(library.voxel_size)), length_scale=length,
        steps_per_batch=result.steps_per_batch, settled_per_batch=result.settled_per_batch,
        seconds=seconds, seed=seed, wall_margin=wall_margin, crop=crop,
    )


def _placements(
    library: Any, plan: PourPlan, positions: np.ndarray, result: EngineResult, tube: Tube,
    engine: str, seed: int, parameters: dict[str, Any], checks: PourChecks,
) -> Placements:
    """The pour's Placements; snapshots (simulation units) scaled like `positions`."""
    length = parameters["length_scale"]
    snapshots = None
    if result.snapshots is not None:
        snapshots = [(np.asarray(pos) * length, np.asarray(quat)) for pos, quat in result.snapshots]
    return Placements(
        indices=plan.indices, positions=positions, quaternions=result.quaternions,
        scales=plan.scales, batches=plan.batches, tube=tube, unit=str(library.unit),
        voxel_size=tuple(library.voxel_size), seed=seed, engine=engine,
        parameters=parameters, checks=checks, snapshots=snapshots,
    )


def _bodies(library: Any, plan: PourPlan, length: float, mass_unit: float) -> list[Body]:
    """The plan's grains as engine bodies in simulation units."""
    bodies = []
    for k in range(len(plan)):
        particle = library[int(plan.indices[k])]
        s = float(plan.scales[k])
        bodies.append(
            Body(
                vertices=np.asarray(particle.mesh.vertices, dtype=np.float64) * (s / length),
                faces=np.asarray(particle.mesh.faces, dtype=np.int64),
                mass=float(particle.mass) * s**3 / mass_unit,
                center_mass=np.asarray(particle.center_mass, dtype=np.float64) * (s / length),
                orientation=plan.quaternions[k],
                spawn_offset=plan.spawn_offsets[k] / length,
                batch=int(plan.batches[k]),
            )
        )
    return bodies
