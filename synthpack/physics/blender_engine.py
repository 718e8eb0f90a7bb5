"""Blender rigid-body engine: pours grains batch by batch with Blender's simulator.

Blender was the simulator of the paper (section 3.3). Its Python module ``bpy`` cannot
live in synthpack's environment (bpy 5.0 needs Python 3.11 and numpy < 2), so this
engine runs :mod:`synthpack.physics.blender_script` in a separate Blender interpreter
and talks to it through files in a temporary directory: ``scene.json`` plus one
``body_NNNNNN.npz`` mesh file per grain in, ``result.json`` out. See
``blender_script.py`` for the simulation itself (batches, settling, locking).

Finding Blender
---------------
Set the environment variable ``SYNTHPACK_BLENDER`` to either

* a Python interpreter that can ``import bpy`` (e.g. ``/path/.venv-blender/bin/python``,
  made by ``bash .ci/make-blender-venv``), or
* a ``blender`` executable (any path whose file name contains "blender"); it is run as
  ``blender --background --factory-startup --python blender_script.py -- ARGS``.

Without the variable, synthpack uses ``.venv-blender/bin/python`` in the current
working directory if it exists, then ``blender`` on the ``PATH``.
"""

from __future__ import annotations

import collections
import json
import logging
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import trimesh

from synthpack.errors import SynthpackInputError
from synthpack.physics.engine import (
    Body,
    EngineResult,
    Material,
    ProgressCallback,
    SettleCriteria,
    TubeSpec,
)

logger = logging.getLogger(__name__)

__all__ = [
    "BlenderError",
    "simulate",
    "find_blender",
    "blender_available",
    "BLENDER_ENV_VAR",
    "MAX_HULL_VERTICES",
]

BLENDER_ENV_VAR = "SYNTHPACK_BLENDER"
"""Environment variable naming the Blender executable or the Python interpreter with bpy."""

LOCAL_VENV = Path(".venv-blender")
"""Virtual environment (relative to the working directory) made by ``.ci/make-blender-venv``."""

SETUP_HINT = (
    "Install bpy with `bash .ci/make-blender-venv` (needs python3.11; creates .venv-blender "
    "in the current directory) or set SYNTHPACK_BLENDER to a `blender` executable or to a "
    "Python interpreter that can `import bpy`."
)

SOLVER_ITERATIONS = 10
"""Constraint solver iterations per substep (Blender's default)."""

MAX_HULL_VERTICES = 64
"""Default cap on the vertices of a grain's collision hull (as in the pybullet engine)."""

SCRIPT = Path(__file__).with_name("blender_script.py")
"""The script Blender runs."""

NO_BPY_EXIT_CODE = 3
"""Exit status of the script when its interpreter cannot import bpy (see blender_script.py)."""

_LAST_FRAME = 1_048_574  # Blender's largest frame number

_BATCH_LINE = re.compile(r"^BATCH (\d+)/(\d+) frames=(\d+) settled=([01])")
_OUTPUT_TAIL_LINES = 40


class BlenderError(RuntimeError):
    """Blender ran but the simulation failed; the message holds the end of its output."""


def _venv_python(venv: Path) -> Path:
    """The interpreter of a virtual environment on this platform."""
    if sys.platform == "win32":
        return venv / "Scripts" / "python.exe"
    return venv / "bin" / "python"


def _is_blender_executable(path: str) -> bool:
    """True for a Blender executable, False for a Python interpreter (judged by file name)."""
    return "blender" in Path(path).name.lower()


def _command_prefix(path: str) -> list[str]:
    """The command that runs a script with the Blender or bpy interpreter at ``path``."""
    if _is_blender_executable(path):
        return [path, "--background", "--factory-startup", "--python-exit-code", "1", "--python"]
    return [path]


def find_blender() -> list[str] | None:
    """Find a Blender (or bpy-enabled Python) to run the simulation with.

    Looks at, in order: the environment variable ``SYNTHPACK_BLENDER`` (a path to a
    ``blender`` executable or to a Python interpreter that has bpy; when it is set but
    the file does not exist, nothing else is tried), ``.venv-blender/bin/python`` in the
    current working directory, ``blender`` on the ``PATH``.

    Returns
    -------
    list of str or None
        The command prefix to which the script path is appended, e.g.
        ``["/x/.venv-blender/bin/python"]`` or ``["/usr/bin/blender", "--background",
        "--factory-startup", "--python-exit-code", "1", "--python"]``; None when no
        Blender was found.
    """
    configured = os.environ.get(BLENDER_ENV_VAR)
    if configured:
        path = shutil.which(configured) or (configured if Path(configured).is_file() else None)
        if path is None:
            logger.warning("%s=%s is not an executable file", BLENDER_ENV_VAR, configured)
            return None
        return _command_prefix(str(Path(path).absolute()))
    local = _venv_python(Path.cwd() / LOCAL_VENV)
    if local.is_file():
        return _command_prefix(str(local))
    on_path = shutil.which("blender")
    if on_path:
        return _command_prefix(on_path)
    return None


def blender_available() -> bool:
    """True when :func:`find_blender` finds a Blender to run (it is not started)."""
    return find_blender() is not None


def _script_command(prefix: list[str], scene: Path, result: Path) -> list[str]:
    """Full command line running the script on ``scene`` and writing ``result``."""
    if _is_blender_executable(prefix[0]):
        return [*prefix, str(SCRIPT), "--", str(scene), str(result)]
    return [*prefix, str(SCRIPT), str(scene), str(result)]


def _validate(
    bodies: Sequence[Body],
    tube: TubeSpec,
    material: Material,
    settle: SettleCriteria,
    max_hull_vertices: int | None,
    fixed_steps: int | None,
    blend_file: str | os.PathLike | None,
) -> None:
    """Raise SynthpackInputError for input Blender cannot simulate."""
    if blend_file is not None and not Path(blend_file).absolute().parent.is_dir():
        raise SynthpackInputError(
            f"cannot save {blend_file}: its folder does not exist; create it or pick another path."
        )
    if len(bodies) == 0:
        raise SynthpackInputError("simulate() got no bodies: pass at least one Body to pour.")
    for name in ("inner_radius", "height", "wall_thickness", "base_thickness"):
        if not getattr(tube, name) > 0:
            raise SynthpackInputError(
                f"TubeSpec.{name} must be > 0, got {getattr(tube, name)}; pass a positive size."
            )
    for name in ("linear_damping", "angular_damping"):
        if not 0 <= getattr(material, name) <= 1:
            raise SynthpackInputError(
                f"Material.{name} must be within [0, 1] for Blender (a fraction of the "
                f"velocity lost per second), got {getattr(material, name)}."
            )
    if not 0 <= material.collision_margin <= 1:
        raise SynthpackInputError(
            "Material.collision_margin must be within [0, 1] simulation units, "
            f"got {material.collision_margin}."
        )
    if not settle.time_step > 0 or settle.substeps < 1:
        raise SynthpackInputError(
            "SettleCriteria needs time_step > 0 and substeps >= 1, "
            f"got {settle.time_step} and {settle.substeps}."
        )
    steps = settle.max_steps if fixed_steps is None else fixed_steps
    if not (isinstance(steps, (int, np.integer)) and 1 <= steps < _LAST_FRAME):
        name = "SettleCriteria.max_steps" if fixed_steps is None else "fixed_steps"
        raise SynthpackInputError(
            f"{name} must be a whole number within [1, {_LAST_FRAME - 1}] (Blender's last "
            f"frame is {_LAST_FRAME}), got {steps!r}."
        )
    if max_hull_vertices is not None and not (
        isinstance(max_hull_vertices, (int, np.integer)) and max_hull_vertices >= 8
    ):
        raise SynthpackInputError(
            f"max_hull_vertices must be a whole number >= 8 or None, got {max_hull_vertices!r}."
        )
    for i, body in enumerate(bodies):
        vertices = np.asarray(body.vertices)
        faces = np.asarray(body.faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 4:
            raise SynthpackInputError(
                f"body {i}: vertices must have shape (V>=4, 3), got {vertices.shape}."
            )
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise SynthpackInputError(
                f"body {i}: faces must have shape (F>0, 3), got {faces.shape}."
            )
        if not body.mass > 0:
            raise SynthpackInputError(f"body {i}: mass must be > 0, got {body.mass}.")


def _collision_hull(
    vertices: np.ndarray, faces: np.ndarray, max_vertices: int | None
) -> trimesh.Trimesh:
    """Convex hull of a grain, simplified by quadric decimation to at most ``max_vertices``."""
    hull = trimesh.Trimesh(vertices, faces, process=False).convex_hull
    if max_vertices is None or len(hull.vertices) <= max_vertices:
        return hull
    # A closed triangulated convex polyhedron with V vertices has 2 V - 4 faces.
    return hull.simplify_quadric_decimation(face_count=2 * max_vertices - 4).convex_hull


def _write_scene(
    directory: Path,
    bodies: Sequence[Body],
    tube: TubeSpec,
    material: Material,
    settle: SettleCriteria,
    options: dict,
) -> Path:
    """Write scene.json and one npz mesh file per body into ``directory``.

    ``options`` holds ``max_hull_vertices``, ``fixed_steps``, ``record_snapshots`` and
    ``blend_file`` of :func:`simulate`.
    """
    blend = options["blend_file"]
    specs = []
    for i, body in enumerate(bodies):
        vertices = np.asarray(body.vertices, dtype=np.float64)
        hull = _collision_hull(vertices, np.asarray(body.faces), options["max_hull_vertices"])
        name = f"body_{i:06d}.npz"
        np.savez(
            directory / name,
            vertices=vertices,
            faces=np.asarray(body.faces, dtype=np.int64),
            hull_vertices=np.asarray(hull.vertices, dtype=np.float64),
            hull_faces=np.asarray(hull.faces, dtype=np.int64),
        )
        specs.append(
            {
                "mesh": name,
                "mass": float(body.mass),
                "center_mass": np.asarray(body.center_mass, dtype=float).tolist(),
                "orientation": np.asarray(body.orientation, dtype=float).tolist(),
                "spawn_offset": np.asarray(body.spawn_offset, dtype=float).tolist(),
                "batch": int(body.batch),
            }
        )
    scene = {
        "tube": {
            "inner_radius": tube.inner_radius,
            "height": tube.height,
            "wall_thickness": tube.wall_thickness,
            "base_thickness": tube.base_thickness,
        },
        "material": {
            "friction": material.friction,
            "restitution": material.restitution,
            "linear_damping": material.linear_damping,
            "angular_damping": material.angular_damping,
            "collision_margin": material.collision_margin,
        },
        "settle": {
            "time_step": settle.time_step,
            "substeps": settle.substeps,
            "linear_speed": settle.linear_speed,
            "angular_speed": settle.angular_speed,
            "quiet_steps": settle.quiet_steps,
            "max_steps": settle.max_steps,
            "min_steps": settle.min_steps,
        },
        "solver_iterations": SOLVER_ITERATIONS,
        "fixed_steps": options["fixed_steps"],
        "record_snapshots": options["record_snapshots"],
        "blend_file": None if blend is None else str(Path(blend).absolute()),
        "bodies": specs,
    }
    path = directory / "scene.json"
    path.write_text(json.dumps(scene))
    return path


def _subprocess_env() -> dict[str, str]:
    """This process's environment without what would make Blender's Python import our packages."""
    env = dict(os.environ)
    for name in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "VIRTUAL_ENV"):
        env.pop(name, None)
    return env


def _run_blender(command: list[str], progress: ProgressCallback | None) -> None:
    """Run Blender, stream its output to the log and to ``progress``; raise on failure."""
    logger.info("running Blender: %s", " ".join(command))
    tail: collections.deque[str] = collections.deque(maxlen=_OUTPUT_TAIL_LINES)
    try:
        process = subprocess.Popen(
            command,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            text=True,
            errors="replace",
            env=_subprocess_env(),
        )
    except OSError as error:
        raise SynthpackInputError(f"cannot start {command[0]}: {error}. {SETUP_HINT}") from error
    with process:
        assert process.stdout is not None
        for line in process.stdout:
            line = line.rstrip("\n")
            tail.append(line)
            logger.debug("blender: %s", line)
            match = _BATCH_LINE.match(line)
            if match:
                done, total, frames, settled = (int(g) for g in match.groups())
                if not settled:
                    logger.warning(
                        "batch %d/%d did not settle within %d steps", done, total, frames
                    )
                if progress is not None:
                    progress(done - 1, total)
        returncode = process.wait()
    output = "\n".join(tail)
    if returncode == NO_BPY_EXIT_CODE:
        raise SynthpackInputError(f"{command[0]} cannot import bpy. {SETUP_HINT}\n{output}")
    if returncode != 0:
        raise BlenderError(
            f"Blender failed (exit status {returncode}) running {' '.join(command)}.\n"
            f"Last {len(tail)} lines of its output:\n{output}"
        )


def simulate(
    bodies: Sequence[Body],
    tube: TubeSpec,
    material: Material,
    settle: SettleCriteria,
    progress: ProgressCallback | None = None,
    *,
    max_hull_vertices: int | None = MAX_HULL_VERTICES,
    fixed_steps: int | None = None,
    record_snapshots: bool = False,
    blend_file: str | os.PathLike | None = None,
) -> EngineResult:
    """Pour ``bodies`` batch by batch into the tube with Blender's rigid-body simulator.

    Each batch spawns at ``(x, y, top + dz)``, falls, settles and is locked (made
    passive) before the next batch, as in the paper (section 3.3.3). Everything is in
    simulation units. Mass ratios are kept, absolute masses are rescaled (only ratios
    matter and Blender has a minimum mass). Each grain collides as its convex hull
    (simplified to ``max_hull_vertices``) grown by ``material.collision_margin``, so
    touching grains keep a gap of about twice the margin. The tube is a box floor (top
    face z = 0; grains rest one margin above it) and a triangle-mesh wall (a polygon
    inscribed in the circle; grains keep two margins from it), raised above
    ``tube.height`` where a batch spawns higher (so no grain escapes over the rim while
    it falls).
    ``material.rolling_friction`` is ignored (Blender has none). Grains never sleep
    (Blender's default: no deactivation).

    Parameters
    ----------
    bodies : sequence of Body
        The grains (particle-local meshes, masses, centres of mass, spawn poses, batches).
    tube : TubeSpec
        The closed-bottom tube, axis along z, inner floor at z = 0.
    material : Material
        Friction, restitution, damping (each within [0, 1]) and collision margin.
    settle : SettleCriteria
        Time step and substeps per frame, rest thresholds, step limits per batch.
    progress : callable, optional
        ``progress(batch_index, n_batches)``, called after each batch is locked.
    max_hull_vertices : int or None
        Simplify collision hulls to at most this many vertices (>= 8) by quadric
        decimation; None keeps the full hulls. Contact cost grows with the hull's
        vertex count.
    fixed_steps : int, optional
        Run every batch for exactly this many frames, with no settle detection (the
        paper's fixed-frame schedule); a batch then counts as settled when all its
        grains are below the speed thresholds on the last frame. None: detect settling.
    record_snapshots : bool
        Also return, after each batch, the poses of all grains placed so far, read back
        from Blender (``EngineResult.snapshots``), to check that locked grains stay put.
    blend_file : str or os.PathLike, optional
        Also save the final pack (tube and grains at their final poses, no physics) as
        this .blend file, to look at in Blender's GUI.

    Returns
    -------
    EngineResult
        Positions (N, 3) of each body's local origin and quaternions (N, 4) (w, x, y, z),
        local -> world, in the order of ``bodies``; steps (frames) and settled flag per
        batch; with ``record_snapshots``, for each batch k the poses of the bodies of
        batches 0..k (in the order of ``bodies``) once batch k had settled.

    Raises
    ------
    SynthpackInputError
        For invalid input, or when no Blender / bpy interpreter is found (the message
        says how to install one).
    BlenderError
        When Blender fails; the message holds the end of its output.
    """
    _validate(bodies, tube, material, settle, max_hull_vertices, fixed_steps, blend_file)
    prefix = find_blender()
    if prefix is None:
        configured = os.environ.get(BLENDER_ENV_VAR)
        found = (
            f"{BLENDER_ENV_VAR}={configured} is not an executable file."
            if configured
            else f"No Blender found: {BLENDER_ENV_VAR} is unset, there is no {LOCAL_VENV}/ in "
            f"{Path.cwd()} and no `blender` on the PATH."
        )
        raise SynthpackInputError(f"The Blender engine needs Blender or bpy. {found} {SETUP_HINT}")
    with tempfile.TemporaryDirectory(prefix="synthpack-blender-") as tmp:
        directory = Path(tmp)
        options = {
            "max_hull_vertices": max_hull_vertices,
            "fixed_steps": None if fixed_steps is None else int(fixed_steps),
            "record_snapshots": bool(record_snapshots),
            "blend_file": blend_file,
        }
        scene = _write_scene(directory, bodies, tube, material, settle, options)
        result_path = directory / "result.json"
        _run_blender(_script_command(prefix, scene, result_path), progress)
        if not result_path.is_file():
            raise BlenderError(
                f"Blender exited without an error but wrote no {result_path.name}: "
                f"check that {prefix[0]} runs Python scripts."
            )
        result = json.loads(result_path.read_text())
    logger.info(
        "Blender %s poured %d grains in %d batches in %.1f s",
        result["blender_version"],
        len(bodies),
        len(result["frames_per_batch"]),
        result["seconds"],
    )
    snapshots = None
    if result["snapshots"] is not None:
        snapshots = [
            (np.reshape(np.asarray(p, float), (-1, 3)), np.reshape(np.asarray(q, float), (-1, 4)))
            for p, q in result["snapshots"]
        ]
    return EngineResult(
        positions=np.asarray(result["positions"], dtype=np.float64).reshape(-1, 3),
        quaternions=np.asarray(result["quaternions"], dtype=np.float64).reshape(-1, 4),
        steps_per_batch=[int(f) for f in result["frames_per_batch"]],
        settled_per_batch=[bool(s) for s in result["settled_per_batch"]],
        snapshots=snapshots,
    )
