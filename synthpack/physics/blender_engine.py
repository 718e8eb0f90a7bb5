"""Blender rigid-body engine: pours grains batch by batch with Blender's simulator.

Blender was the simulator of the paper (section 3.3). Its Python module ``bpy`` cannot
live in synthpack's environment (bpy 5.0 needs Python 3.11 and numpy < 2), so this
engine runs :mod:`synthpack.physics.blender_script` in a separate Blender interpreter,
one per pour. The batch loop stays here, in synthpack's driver
(:func:`synthpack.physics.driver.drive`, the same for every engine, with compaction and
the retiring of buried grains): this engine's :class:`~synthpack.physics.driver.World`
forwards each hook to the script as one JSON line on its stdin and reads the reply from
its stdout. The scene reaches the script as a saved :class:`~synthpack.physics.scene.Scene`
(``scene.json``, ``bodies.npz``) plus the grains' collision hulls (``hulls.npz``) in a
temporary folder. See ``blender_script.py`` for the calls and how Blender carries them out.

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
import shutil
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Sequence

import numpy as np

from .._shared.schema import in_range, setting
from ..errors import SynthpackInputError
from .driver import LockedBatch, World
from .engine import Engine
from .hulls import convex_hull, simplify_hull
from .scene import EngineConfig, Material, Scene, SettleCriteria

logger = logging.getLogger(__name__)

__all__ = [
    "BlenderEngine",
    "BlenderConfig",
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

REPLY = "@synthpack-reply@ "
"""What starts each of the script's reply lines on its stdout (see blender_script.py)."""

HULLS_FILE = "hulls.npz"
"""The grains' collision hulls, next to the saved scene (see :func:`_save_scene`)."""

LAST_FRAME = 1_048_574
"""Blender's largest frame number: a batch runs for fewer frames than this."""

_OUTPUT_TAIL_LINES = 40


class BlenderError(RuntimeError):
    """Blender ran but the simulation failed; the message holds the end of its output."""


@dataclass(frozen=True)
class BlenderConfig(EngineConfig):
    """Options of the Blender engine (``engine_options`` of :func:`~synthpack.physics.pour`).

    Attributes
    ----------
    fixed_steps : int or None
        As in :class:`~synthpack.physics.scene.EngineConfig`, in frames, below
        :data:`LAST_FRAME`; a batch then counts as settled when all its grains are below
        the speed thresholds on the last frame.
    blend_file : str or None
        Also save the final pack (tube and grains at their final poses, no physics) as
        this .blend file, to look at in Blender's GUI; its folder must exist.

    See :class:`~synthpack.physics.scene.EngineConfig` for ``max_hull_vertices`` and
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

    Packing to a target (:mod:`synthpack.physics.compaction`) comes through the driver: a
    compacted batch falls at the lowered friction; once it is nearly still, it gets the
    material's friction back and the timeline restarts with the batch where it is, at rest
    (it loses the little speed it had left, unlike in pybullet). A spaced batch collides
    as its hulls inflated about the centre of mass; Blender takes a grain's inertia from
    its collision shape, so a spaced grain's is its shell's. Measured on 150 grains of the
    ``large`` sample (a free pour packs at 0.527): targets 0.57 and 0.30 were reached
    (0.572, 0.304).

    :meth:`simulate` raises :class:`BlenderError` when Blender fails; the message holds
    the end of its output.
    """

    name = "blender"
    Options = BlenderConfig

    def check(self, material: Material, settle: SettleCriteria, options: EngineConfig) -> None:
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

    def open(self, scene: Scene) -> World:
        """A Blender interpreter of its own holding the scene's tube (:class:`_BlenderWorld`)."""
        return _BlenderWorld(require_blender(), scene)


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


def _script_command(prefix: list[str], scene: Path) -> list[str]:
    """Full command line running the script on ``scene``."""
    if _is_blender_executable(prefix[0]):
        return [*prefix, str(SCRIPT), "--", str(scene)]
    return [*prefix, str(SCRIPT), str(scene)]


def _save_scene(directory: Path, scene: Scene) -> Path:
    """Save `scene` into `directory` (:meth:`Scene.save`) with :data:`HULLS_FILE`; the scene file's path.

    :data:`HULLS_FILE` holds each grain's collision hull (simplified to
    ``max_hull_vertices``), particle-local frame, laid out as the bodies' meshes are.
    """
    hulls = [simplify_hull(convex_hull(np.asarray(b.vertices, dtype=np.float64)), scene.options.max_hull_vertices)
             for b in scene.bodies]
    vertices = [np.asarray(h.vertices, dtype=np.float64) for h in hulls]
    faces = [np.asarray(h.faces, dtype=np.int64) for h in hulls]
    np.savez(
        directory / HULLS_FILE,
        vertices=np.concatenate(vertices),
        faces=np.concatenate(faces),
        vertex_offsets=np.cumsum([0, *map(len, vertices)], dtype=np.int64),
        face_offsets=np.cumsum([0, *map(len, faces)], dtype=np.int64),
    )
    return scene.save(directory)


def _subprocess_env() -> dict[str, str]:
    """This process's environment without what would make Blender's Python import our packages."""
    env = dict(os.environ)
    for name in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "VIRTUAL_ENV"):
        env.pop(name, None)
    return env


class _BlenderWorld(World):
    """The pour in a Blender interpreter of its own: each hook is one call to ``blender_script.py``.

    Raises :class:`BlenderError` when Blender fails (the message holds the end of its
    output), SynthpackInputError when the interpreter cannot import bpy.
    """

    def __init__(self, prefix: list[str], scene: Scene) -> None:
        self._scene, self._batches = scene, 0
        self._folder = tempfile.TemporaryDirectory(prefix="synthpack-blender-")
        self._tail: collections.deque[str] = collections.deque(maxlen=_OUTPUT_TAIL_LINES)
        self._process: subprocess.Popen[str] | None = None
        try:
            self._command = _script_command(prefix, _save_scene(Path(self._folder.name), scene))
            logger.info("running Blender: %s", " ".join(self._command))
            try:
                self._process = subprocess.Popen(
                    self._command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                    text=True, errors="replace", env=_subprocess_env(),
                )
            except OSError as error:
                raise SynthpackInputError(f"cannot start {self._command[0]}: {error}. {SETUP_HINT}") from error
            self._version = self._call("open", hulls=HULLS_FILE, solver_iterations=SOLVER_ITERATIONS)["blender_version"]
        except BaseException:
            self._stop()
            raise

    def _call(self, name: str, **args: Any) -> dict[str, Any]:
        """Send one call to the script and return its reply; Blender's other output goes to the log."""
        process = self._process
        assert process is not None and process.stdin is not None and process.stdout is not None
        try:
            process.stdin.write(json.dumps({"call": name, "args": args}) + "\n")
            process.stdin.flush()
        except BrokenPipeError:
            pass  # it has ended: its output and exit status say why
        for line in iter(process.stdout.readline, ""):
            line = line.rstrip("\n")
            if line.startswith(REPLY):
                return json.loads(line[len(REPLY):])
            if line:
                self._tail.append(line)
                logger.debug("blender: %s", line)
        raise self._failure(name)

    def _failure(self, name: str) -> Exception:
        """The error to raise for a script that ended before replying to call `name`."""
        assert self._process is not None
        returncode = self._process.wait()
        output = "\n".join(self._tail)
        if returncode == NO_BPY_EXIT_CODE:
            return SynthpackInputError(f"{self._command[0]} cannot import bpy. {SETUP_HINT}\n{output}")
        if returncode == 0:
            return BlenderError(f"Blender exited without an error but did not answer {name!r}: "
                                f"check that {self._command[0]} runs Python scripts.\n{output}")
        return BlenderError(
            f"Blender failed (exit status {returncode}) running {' '.join(self._command)}.\n"
            f"Last {len(self._tail)} lines of its output:\n{output}"
        )

    def add_batch(self, members: np.ndarray, positions: np.ndarray, friction: float, inflation: np.ndarray) -> None:
        self._call("add_batch", members=np.asarray(members).tolist(), positions=np.asarray(positions).tolist(),
                   friction=float(friction), inflation=np.asarray(inflation, dtype=float).tolist())

    def settle(self, criteria: SettleCriteria, fixed_steps: int | None) -> tuple[int, bool]:
        reply = self._call("settle", criteria=asdict(criteria), fixed_steps=fixed_steps)
        return int(reply["steps"]), bool(reply["settled"])

    def set_friction(self, friction: float) -> None:
        self._call("set_friction", friction=float(friction))

    def lock(self) -> LockedBatch:
        reply = self._call("lock")
        self._batches += 1
        return LockedBatch(np.asarray(reply["positions"], dtype=np.float64).reshape(-1, 3),
                           np.asarray(reply["quaternions"], dtype=np.float64).reshape(-1, 4),
                           [np.asarray(h, dtype=np.float64).reshape(-1, 3) for h in reply["hulls"]])

    def retire(self, indices: Sequence[int]) -> None:
        self._call("retire", indices=[int(i) for i in indices])

    def poses(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        reply = self._call("poses", indices=np.asarray(indices).tolist())
        return (np.asarray(reply["positions"], dtype=np.float64).reshape(-1, 3),
                np.asarray(reply["quaternions"], dtype=np.float64).reshape(-1, 4))

    def close(self) -> None:
        """Let the script save the .blend file (when asked for) and end."""
        try:
            seconds = self._call("close")["seconds"]
            if self._process is not None and self._process.wait() != 0:
                raise self._failure("close")
            logger.info("Blender %s poured %d grains in %d batches in %.1f s",
                        self._version, len(self._scene.bodies), self._batches, seconds)
        finally:
            self._stop()

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if kind is None:
            self.close()
        else:  # the pour failed: no .blend file, and Blender is stopped rather than asked to end
            self._stop()

    def _stop(self) -> None:
        """End the Blender process if it still runs, and delete the scene's folder."""
        process = self._process
        if process is not None:
            if process.poll() is None:
                process.kill()
            process.wait()
            for stream in (process.stdin, process.stdout):
                if stream is not None:
                    stream.close()
        self._folder.cleanup()
