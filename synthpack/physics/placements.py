"""The result of a pour: where every grain ended up, plus how it got there."""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from .._shared.strict_json import dumps as strict_json
from ..io.atomic import Output, atomic_file
from ..errors import SynthpackInputError
from .checks import PourChecks
from .container import Tube

logger = logging.getLogger(__name__)

__all__ = ["Placements", "FORMAT_VERSION", "rotation_matrices"]

#: Version of the JSON layout written by :meth:`Placements.save`: 2 adds ``grains`` (deformed grains).
#: Placements without it are written as version 1, byte for byte as before, and both are read.
FORMAT_VERSION = 2
_READ_VERSIONS = (1, 2)
_FORMAT = "synthpack.placements"


def _is_placements_file(path: Path) -> bool:
    try:
        return json.loads(path.read_text(encoding="utf-8")).get("format") == _FORMAT
    except (OSError, ValueError, AttributeError):
        return False


#: A placements file: an earlier one is replaced, any other file is refused.
PLACEMENTS_OUTPUT = Output("placements file", folder=False, is_ours=_is_placements_file)


def rotation_matrices(quaternions: np.ndarray) -> np.ndarray:
    """(N, 3, 3) float64 rotation matrices (local -> world) of (N, 4) quaternions ``(w, x, y, z)``."""
    return Rotation.from_quat(quaternions, scalar_first=True).as_matrix()


@dataclass
class Placements:
    """Final poses of the poured grains (paper section 3.3's simulation result).

    Positions are in physical units (the library's ``unit``) in the world frame
    (x, y, z; z up the tube axis, inner floor at z = 0) and locate each grain's
    particle-LOCAL ORIGIN (the centre of its crop box; of the deformed grain's crop box
    when `grains` is set). Rotations map local to world
    coordinates; the grain's mesh is scaled by ``scales`` about its local origin
    before it is rotated.

    Attributes
    ----------
    indices : numpy.ndarray
        (N,) int64 library index of each grain.
    positions : numpy.ndarray
        (N, 3) float64 world position of each grain's local origin.
    quaternions : numpy.ndarray
        (N, 4) float64 unit quaternions (w, x, y, z), local -> world, with w >= 0.
    scales : numpy.ndarray
        (N,) float64 scale factors.
    batches : numpy.ndarray
        (N,) int64 batch number of each grain.
    tube : Tube
        The container, physical units.
    unit : str
        Physical length unit.
    voxel_size : tuple of 3 float
        (dz, dy, dx) of the library's source scan (the default reconstruction grid).
    seed : int
        Seed of the pour.
    engine : str
        Engine that ran it (``"pybullet"`` or ``"blender"``).
    parameters : dict
        The pour's parameters (JSON-able): n_particles, batch_size, scale,
        size_classes, material, settle, length_scale, engine options.
    checks : PourChecks
        Quality checks and engine statistics.
    grains : dict or None
        None: placement ``i`` is library grain ``indices[i]`` as it is. Otherwise
        (JSON-able) how each placement's grain was made from library grain
        ``indices[i]``: e.g. the free-form deformation record of
        `synthpack.library.deform.PackGrains.record` (method, strength, lattice, and per
        placement a seed and a damping factor), which redoes it
        (`synthpack.library.deform.redo_grains`).
    snapshots : list of (numpy.ndarray, numpy.ndarray) or None
        Diagnostic, only when asked for and NOT saved: per batch k, positions (n_k, 3)
        and quaternions (n_k, 4) of the grains of batches 0..k right after batch k
        was locked.
    """

    indices: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    scales: np.ndarray
    batches: np.ndarray
    tube: Tube
    unit: str
    voxel_size: tuple[float, float, float]
    seed: int
    engine: str
    parameters: dict[str, Any]
    checks: PourChecks
    grains: dict[str, Any] | None = None
    snapshots: list[tuple[np.ndarray, np.ndarray]] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.indices = np.asarray(self.indices, dtype=np.int64).reshape(-1)
        n = len(self.indices)
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(n, 3)
        quaternions = np.asarray(self.quaternions, dtype=np.float64).reshape(n, 4)
        self.quaternions = quaternions * np.where(quaternions[:, :1] < 0, -1.0, 1.0)
        self.scales = np.asarray(self.scales, dtype=np.float64).reshape(n)
        self.batches = np.asarray(self.batches, dtype=np.int64).reshape(n)
        self.voxel_size = tuple(float(v) for v in self.voxel_size)  # type: ignore[assignment]

    def __len__(self) -> int:
        return int(self.indices.shape[0])

    def __repr__(self) -> str:
        return (
            f"Placements(n={len(self)}, batches={int(self.batches.max()) + 1 if len(self) else 0}, "
            f"engine={self.engine!r}, seed={self.seed}, unit={self.unit!r}, "
            f"packing={self.checks.packing_fraction:.3f})"
        )

    def rotations(self) -> Rotation:
        """The rotations as one :class:`scipy.spatial.transform.Rotation` of length N."""
        return Rotation.from_quat(self.quaternions, scalar_first=True)

    def rotation_matrices(self) -> np.ndarray:
        """(N, 3, 3) float64 rotation matrices R (local -> world: ``x_world = R @ x_local``)."""
        return rotation_matrices(self.quaternions)

    def euler_angles(self) -> np.ndarray:
        """(N, 3) float64 angles ``(theta, phi, psi)`` in radians (paper eq. 2-4).

        ``R = Rz(psi) @ Ry(phi) @ Rx(theta)``: rotations about the FIXED x, then y,
        then z axes (scipy's extrinsic ``"xyz"`` sequence). theta, psi in (-pi, pi],
        phi in [-pi/2, pi/2].
        """
        return self.rotations().as_euler("xyz")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dictionary (without `snapshots`); version 1 (no ``grains`` key) when `grains` is None."""
        data = {
            "format": _FORMAT,
            "version": FORMAT_VERSION if self.grains is not None else 1,
            "unit": self.unit,
            "voxel_size": list(self.voxel_size),
            "seed": self.seed,
            "engine": self.engine,
            "tube": self.tube.to_dict(),
            "parameters": self.parameters,
            "checks": self.checks.to_dict(),
            "indices": self.indices.tolist(),
            "positions": self.positions.tolist(),
            "quaternions": self.quaternions.tolist(),
            "scales": self.scales.tolist(),
            "batches": self.batches.tolist(),
        }
        if self.grains is not None:
            data["grains"] = self.grains
        return data

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the placements as JSON, atomically (temporary name, then rename).

        Earlier placements at `path` are replaced; any other file only with `overwrite`.

        Returns
        -------
        pathlib.Path
            The written file.
        """
        final = Path(path)
        with atomic_file(final, PLACEMENTS_OUTPUT, overwrite=overwrite) as staging:
            staging.write_text(strict_json(self.to_dict(), indent=1), encoding="utf-8")
        logger.debug("Saved %d placements to %s", len(self), final)
        return final

    @classmethod
    def load(cls, path: str | os.PathLike) -> Placements:
        """Read placements written by :meth:`save`.

        Raises
        ------
        SynthpackInputError
            If the file is missing, not JSON, or not a placements file of a known
            version.
        """
        source = Path(path)
        try:
            data = json.loads(source.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise SynthpackInputError(
                f"No placements file at {source}; run `synthpack pour` to make one."
            ) from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
            raise SynthpackInputError(
                f"Cannot read placements file {source} ({error}); it is corrupt: pour again."
            ) from None
        if not isinstance(data, dict) or data.get("format") != _FORMAT:
            raise SynthpackInputError(f"{source} is not a synthpack placements file.")
        if data.get("version") not in _READ_VERSIONS:
            raise SynthpackInputError(
                f"{source} has placements format version {data.get('version')!r}; this "
                f"synthpack reads versions {', '.join(map(str, _READ_VERSIONS))}: pour again."
            )
        try:
            return cls(
                indices=data["indices"],
                positions=data["positions"],
                quaternions=data["quaternions"],
                scales=data["scales"],
                batches=data["batches"],
                tube=Tube.from_dict(data["tube"]),
                unit=str(data["unit"]),
                voxel_size=data["voxel_size"],
                seed=int(data["seed"]),
                engine=str(data["engine"]),
                parameters=dict(data["parameters"]),
                checks=PourChecks.from_dict(data["checks"]),
                grains=data.get("grains"),
            )
        except (KeyError, TypeError, ValueError) as error:
            raise SynthpackInputError(
                f"Placements file {source} is incomplete or corrupt ({error!r}): pour again."
            ) from None
