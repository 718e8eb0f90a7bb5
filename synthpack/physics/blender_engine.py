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
:meth:`BlenderEngine.available` says whether one is found.
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
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .._shared.schema import in_range, setting
from ..errors import SynthpackInputError
from .engine import (
    Body,
    Engine,
    EngineOptions,
    EngineResult,
    Material,
    ProgressCallback,
    SettleCriteria,
    TubeSpec,
)
from .hulls import convex_hull, simplify_hull

logger = logging.getLogger(__name__)

__all__ = [
    "BlenderEngine",
    "BlenderOptions",
    "BlenderError",
    "find_blender",
    "require_blender",
    "BLENDER_ENV_VAR",
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

SCRIPT = Path(__file__).with_name("blender_script.py")
"""The script Blender runs."""

NO_BPY_EXIT_CODE = 3
"""Exit status of the script when its interpreter cannot import bpy (see blender_script.py)."""

LAST_FRAME = 1_048_574
"""Blender's largest frame number: a batch runs for fewer frames than this."""

_BATCH_LINE = re.compile(r"^BATCH (\d+)/(\d+) frames=(\d+) settled=([01])")
_OUTPUT_TAIL_LINES = 40


class BlenderError(RuntimeError):
    """Blender ran but the simulation failed; the message holds the end of its output."""


@dataclass(frozen=True)
class BlenderOptions(EngineOptions):
    """Options of the Blender engine (``engine_options`` of :func:`~synthpack.physics.pour`).

    Attributes
    ----------
    fixed_steps : int or None
        As in :class:`~synthpack.physics.engine.EngineOptions`, in frames, below
        :data:`LAST_FRAME`; a batch then counts as settled when all its grains are below
        the speed thresholds on the last frame.
    blend_file : str or None
        Also save the final pack (tube and grains at their final poses, no physics) as
        this .blend file, to look at in Blender's GUI; its folder must exist.

    See :class:`~synthpack.physics.engine.EngineOptions` for ``max_hull_vertices`` and
    ``record_snapshots``.
    """

    fixed_steps: int | None = setting(
        None, in_range(1, LAST_FRAME - 1),
        "run every batch for exactly this many frames, without settle detection",
    )
    blend_file: str | None = setting(None, None, "also save the final pack as this .blend file")


class BlenderEngine(Engine):
    """Blender's rigid-body simulator, the paper's (section 3.3), in a separate interpreter.

    Each batch spawns at ``(x, y, top + dz)``, falls, settles and is locked (made
    passive) before the next batch, as in the paper (section 3.3.3). Mass ratios are
    kept, absolute masses are rescaled (only ratios matter and Blender has a minimum
    mass). Each grain collides as its convex hull (simplified to ``max_hull_vertices``,
    :mod:`synthpack.physics.hulls`) grown by ``material.collision_margin``, so touching
    grains keep a gap of about twice the margin. The tube is a box floor (top face
    z = 0; grains rest one margin above it) and a triangle-mesh wall (a polygon
    inscribed in the circle; grains keep two margins from it), raised above
    ``tube.height`` where a batch spawns higher (so no grain escapes over the rim
    while it falls). ``material.rolling_friction`` is ignored (Blender has none).
    Grains never sleep (Blender's default: no deactivation). With ``record_snapshots``
    the poses are read back from Blender after each batch.

    :meth:`simulate` raises :class:`BlenderError` when Blender fails; the message holds
    the end of its output.
    """

    name = "blender"
    Options = BlenderOptions

    def check(self, material: Material, settle: SettleCriteria, options: EngineOptions) -> None:
        """The common checks, hulls only, Blender's collision-margin and frame limits and the .blend file's folder."""
        super().check(material, settle, options)
        if material.collision_shape != "hull":
            raise SynthpackInputError(
                f"The blender engine collides grains as convex hulls only, not as a "
                f"{material.collision_shape}; use collision shape 'hull' or the pybullet engine."
            )
        if not material.collision_margin <= 1:
            raise SynthpackInputError(
                "Material.collision_margin must be within [0, 1] simulation units, "
                f"got {material.collision_margin}."
            )
        if options.fixed_steps is None and not settle.max_steps < LAST_FRAME:
            raise SynthpackInputError(
                f"SettleCriteria.max_steps must be a whole number within [1, {LAST_FRAME - 1}] "
                f"(Blender's last frame is {LAST_FRAME}), got {settle.max_steps!r}."
            )
        blend_file = options.blend_file
        if blend_file is not None and not Path(blend_file).absolute().parent.is_dir():
            raise SynthpackInputError(
                f"cannot save {blend_file}: its folder does not exist; create it or pick another path."
            )

    def check_available(self) -> None:
        """Raise SynthpackInputError, with a setup hint, when no Blender or bpy is found."""
        require_blender()

    def _simulate(
        self,
        bodies: Sequence[Body],
        tube: TubeSpec,
        material: Material,
        settle: SettleCriteria,
        options: BlenderOptions,
        progress: ProgressCallback | None,
        compaction: None = None,
    ) -> EngineResult:
        # no packing to a target here (supports_compaction is False): Engine.simulate refuses it
        prefix = require_blender()
        with tempfile.TemporaryDirectory(prefix="synthpack-blender-") as tmp:
            directory = Path(tmp)
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
        return _engine_result(result)


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


def require_blender() -> list[str]:
    """The command prefix of :func:`find_blender`.

    Raises
    ------
    SynthpackInputError
        When no Blender or bpy interpreter is found; the message says how to install one.
    """
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
    return prefix


def _script_command(prefix: list[str], scene: Path, result: Path) -> list[str]:
    """Full command line running the script on ``scene`` and writing ``result``."""
    if _is_blender_executable(prefix[0]):
        return [*prefix, str(SCRIPT), "--", str(scene), str(result)]
    return [*prefix, str(SCRIPT), str(scene), str(result)]


def _write_scene(
    directory: Path,
    bodies: Sequence[Body],
    tube: TubeSpec,
    material: Material,
    settle: SettleCriteria,
    options: BlenderOptions,
) -> Path:
    """Write scene.json and one npz mesh file per body into ``directory``."""
    blend = options.blend_file
    specs = []
    for i, body in enumerate(bodies):
        vertices = np.asarray(body.vertices, dtype=np.float64)
        hull = simplify_hull(convex_hull(vertices), options.max_hull_vertices)
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
        "fixed_steps": options.fixed_steps,
        "record_snapshots": options.record_snapshots,
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


def _engine_result(result: dict) -> EngineResult:
    """The EngineResult of the script's result.json."""
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
