"""Pouring grains into a virtual tube: batched, locked rigid-body simulation (paper 3.3).

:func:`pour` draws a pour plan from one seed (:mod:`.plan`), converts it to
simulation units, runs an engine batch by batch (each batch falls, settles and is
locked before the next enters), converts the poses back to physical units, checks
the result (:mod:`.checks`) and returns :class:`Placements`.

Simulation units: 1 length unit = the library's median equivalent diameter (grains
are ~1 unit across; gravity 9.81 units/s^2), 1 mass unit = the library's median
grain mass. Engines: ``"pybullet"`` (default, :mod:`.pybullet_engine`) and
``"blender"`` (:mod:`.blender_engine`, bpy in a separate interpreter, as in the
paper).
"""

from __future__ import annotations

import importlib
import inspect
import logging
import time
from dataclasses import asdict
from typing import Any, Sequence

import numpy as np
from tqdm.auto import tqdm

from ..errors import SynthpackInputError
from .checks import PourChecks, compute_checks
from .config import ENGINE_MODULES as ENGINES
from .config import PourConfig
from .container import Tube
from .engine import Body, EngineResult, Material, SettleCriteria
from .placements import Placements
from .plan import make_plan, parse_scale

logger = logging.getLogger(__name__)

__all__ = ["pour", "Placements", "PourConfig", "Tube", "Material", "SettleCriteria", "PourChecks", "ENGINES"]


def pour(
    library: Any,
    n_particles: int,
    batch_size: int,
    engine: str = "pybullet",
    seed: int = 0,
    container: Tube | None = None,
    scale: float | Sequence[float] = 1.0,
    size_classes: Sequence[Sequence[float]] | None = None,
    material: Material | None = None,
    settle: SettleCriteria | None = None,
    progress: bool = True,
    engine_options: dict[str, Any] | None = None,
) -> Placements:
    """Pour `n_particles` grains of `library` into a tube, `batch_size` at a time.

    Parameters
    ----------
    library : ParticleLibrary
        The grains: meshes in the local frame (physical units), masses
        (density x volume, paper eq. 1), centres of mass.
    n_particles : int
        Number of grains to pour (drawn from the library with replacement).
    batch_size : int
        Grains per batch; each batch settles and is locked before the next falls.
    engine : {"pybullet", "blender"}
        Rigid-body engine.
    seed : int
        Seed of every random choice (grains, orientations, scales, spawn points).
    container : Tube, optional
        The tube, physical units; default :meth:`Tube.for_library`.
    scale : float or (float, float)
        Scale factor of the grains, or a (min, max) range drawn per grain.
    size_classes : sequence of (d_min, d_max, fraction), optional
        Target size distribution by number fraction over equivalent-diameter
        classes (physical units), as by sifting.
    material : Material, optional
        Friction, restitution, damping; default ``Material()``.
    settle : SettleCriteria, optional
        Time step and settle detection; default ``SettleCriteria()``.
    progress : bool
        Show a progress bar over batches.
    engine_options : dict, optional
        Extra keyword arguments of the engine's ``simulate`` (pybullet:
        ``convex_decomposition``, ``max_hull_vertices``, ``record_snapshots``,
        ``fixed_steps``, ``allow_sleeping``; see
        :func:`synthpack.physics.pybullet_engine.simulate`).

    Returns
    -------
    Placements
        Final poses in physical units, the tube, the parameters and the checks.

    Raises
    ------
    SynthpackInputError
        For a bad count, batch size, engine, option, scale, size class or tube.
    """
    n_particles = _count(n_particles, "n_particles")
    batch_size = _count(batch_size, "batch_size")
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SynthpackInputError(f"seed must be a whole number >= 0, got {seed!r}.")
    seed = int(seed)
    if len(library) == 0:
        raise SynthpackInputError(
            "The particle library is empty; build it from a labelled scan with grains in it."
        )
    simulate = _engine(engine)
    options = dict(engine_options or {})
    try:
        inspect.signature(simulate).bind([], None, None, None, None, **options)
    except TypeError:
        raise SynthpackInputError(
            f"Engine {engine!r} does not take the options {sorted(options)}; see "
            f"help({ENGINES[engine]}.simulate)."
        ) from None
    material = material if material is not None else Material()
    settle = settle if settle is not None else SettleCriteria()
    _check_material(material)
    _check_settle(settle)
    low, high = parse_scale(scale)
    tube = container
    if tube is None:
        tube = Tube.for_library(library, n_particles, scale=high)
    if not isinstance(tube, Tube):
        raise SynthpackInputError(f"container must be a Tube, got {type(tube).__name__}.")

    plan = make_plan(library, n_particles, batch_size, tube, seed=seed, scale=scale,
                     size_classes=size_classes)
    length = float(np.median(np.asarray(library.equivalent_diameters, dtype=float)))
    mass_unit = float(np.median([library[i].mass for i in range(len(library))]))
    bodies = _bodies(library, plan, length, mass_unit)

    logger.info("Pouring %d grains in %d batches with %s (seed %d)",
                n_particles, plan.n_batches, engine, seed)
    bar = tqdm(total=plan.n_batches, desc="pouring", unit="batch", disable=not progress)
    start = time.perf_counter()
    try:
        result: EngineResult = simulate(
            bodies, tube.spec(length), material, settle,
            lambda done, total: bar.update(1), **options,
        )
    finally:
        bar.close()
    seconds = time.perf_counter() - start

    positions = np.asarray(result.positions, dtype=float) * length
    voxel = float(min(library.voxel_size))
    checks = compute_checks(
        [(np.asarray(library[i].mesh.vertices, dtype=float), np.asarray(library[i].mesh.faces))
         for i in range(len(library))],
        plan.indices, positions, result.quaternions, plan.scales, tube,
        voxel_size=voxel, length_scale=length,
        steps_per_batch=result.steps_per_batch, settled_per_batch=result.settled_per_batch,
        seconds=seconds, seed=seed,
    )
    parameters = {
        "n_particles": n_particles,
        "batch_size": batch_size,
        "scale": [low, high],
        "size_classes": [list(map(float, c)) for c in size_classes] if size_classes else None,
        "material": asdict(material),
        "settle": asdict(settle),
        "length_scale": length,
        "mass_unit": mass_unit,
        "engine_options": options,
    }
    snapshots = None
    if result.snapshots is not None:
        snapshots = [(np.asarray(pos) * length, np.asarray(quat)) for pos, quat in result.snapshots]
    return Placements(
        indices=plan.indices,
        positions=positions,
        quaternions=result.quaternions,
        scales=plan.scales,
        batches=plan.batches,
        tube=tube,
        unit=str(library.unit),
        voxel_size=tuple(library.voxel_size),
        seed=int(seed),
        engine=engine,
        parameters=parameters,
        checks=checks,
        snapshots=snapshots,
    )


def _count(value: Any, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise SynthpackInputError(f"{name} must be a whole number >= 1, got {value!r}.")
    return int(value)


def _check_material(material: Material) -> None:
    if not isinstance(material, Material):
        raise SynthpackInputError(f"material must be a Material, got {type(material).__name__}.")
    ranges = {
        "friction": (0.0, np.inf), "restitution": (0.0, 1.0), "rolling_friction": (0.0, np.inf),
        "linear_damping": (0.0, 1.0), "angular_damping": (0.0, 1.0),
        "collision_margin": (0.0, np.inf),
    }
    for name, (low, high) in ranges.items():
        value = getattr(material, name)
        if not (isinstance(value, (int, float)) and low <= value <= high):
            raise SynthpackInputError(
                f"Material.{name} must be a number in [{low:g}, {high:g}], got {value!r}."
            )


def _check_settle(settle: SettleCriteria) -> None:
    if not isinstance(settle, SettleCriteria):
        raise SynthpackInputError(f"settle must be a SettleCriteria, got {type(settle).__name__}.")
    for name in ("time_step", "linear_speed", "angular_speed"):
        value = getattr(settle, name)
        if not (isinstance(value, (int, float)) and 0 < value < np.inf):
            raise SynthpackInputError(f"SettleCriteria.{name} must be > 0, got {value!r}.")
    for name in ("substeps", "quiet_steps", "max_steps"):
        value = getattr(settle, name)
        if not (isinstance(value, int) and value >= 1):
            raise SynthpackInputError(
                f"SettleCriteria.{name} must be a whole number >= 1, got {value!r}."
            )
    if not (isinstance(settle.min_steps, int) and 0 <= settle.min_steps <= settle.max_steps):
        raise SynthpackInputError(
            "SettleCriteria.min_steps must be a whole number in [0, max_steps], "
            f"got {settle.min_steps!r}."
        )


def _engine(name: str):
    if name not in ENGINES:
        raise SynthpackInputError(
            f"Unknown engine {name!r}; choose one of: {', '.join(ENGINES)}."
        )
    return importlib.import_module(ENGINES[name]).simulate


def _bodies(library: Any, plan, length: float, mass_unit: float) -> list[Body]:
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
