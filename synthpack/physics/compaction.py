"""Packing to a target solid fraction: how each batch is compacted or spaced before it is locked.

A free pour of rigid grains settles at one packing fraction (about 0.5 for the
built-in samples), but a scan's bulk can be denser (sand, 0.56-0.61) or much looser
(aggregates floating in cement paste, 0.25). ``pour.target_solid_fraction`` asks for
a value; the pour reaches it batch by batch, keeping the paper's batching and
locking, with one knob ``u`` per batch (:class:`BatchCompaction`):

* ``u > 0``, **denser than a free pour**: compaction by a friction schedule, as
  DEM codes (LIGGGHTS, YADE) prepare dense packings. The batch falls with its friction
  lowered to ``friction * (1 - u) + SETTLE_FRICTION * u`` until it is nearly still
  (speeds below :data:`FALL_QUIET` times the settle thresholds, at most
  :data:`FALL_STEPS` steps), so its grains slide into the voids below them; then it
  gets the material's friction back and settles as usual before it is locked.
  Tapping (every grain of the batch thrown up and left to fall back) was measured
  too and left out: on ``large`` (300 grains, target 0.62) two taps after the
  low-friction fall gave 0.593 against 0.602 without, for 6% more steps. Waiting for
  the low-friction fall to come fully to rest gave no more density than stopping at
  8x the speed thresholds (0.596-0.603 against 0.610) for 1.3-1.5x the steps.
* ``1 < u <= 2``, **denser than these hulls pack**, for an engine that can shrink
  collision shells (:attr:`~synthpack.physics.engine.Engine.shrinks_shells`): full
  compaction, with the batch colliding as shells shrunk about their centre of mass by
  ``(u - 1) * max_shrink`` of their size. Grains collide as their convex hulls, and
  hulls cannot nest, so concave grains (sand: mean mesh volume over hull volume
  ``c`` about 0.8) pack looser than the real ones, which do; a shell shrunk by
  ``max_shrink = 1 - c^(1/3)`` holds the grain's volume. A pour of sand reached
  0.52 under full compaction against the scan's 0.58, as the hulls' own fraction
  (``0.58 / c`` would be 0.72) is more than any random packing holds. The grains are
  rendered at their true size, so neighbours may overlap a little where their
  concavities do not meet (the checks report the penetration and the overlap). A
  batch gets ``u > 1`` only once the prior (:class:`PackingPrior`, which scales the hulls'
  packing by ``c``), or the compacted bulk layers (``u > 0``) scaled to full compaction by their
  measured fraction over the prior's, say that full compaction falls short of the target by more
  than half of :data:`TARGET_TOLERANCE`: a pour that full compaction brings to the target never
  shrinks a shell, and one it cannot bring there shrinks them from the first batch rather than
  after layers of full compaction (a narrow tube of sand, whose first bulk layer is measured after
  half of its batches, reached 0.536 against the scan's 0.596 when only the layers could start
  it); the knob rises by at most ``_MAX_SHRINK_STEP`` a batch above 1, and falls by at most
  ``_MAX_KNOB_FALL`` after a compacted batch, as thin layers measure noisily.
* ``u < 0``, **looser than a free pour**: the grains collide as shells inflated by
  ``-u`` of their size about their centre of mass (a spacing, as in the coarse-grain
  and "collision distance" options of DEM codes), so they settle apart; they are
  rendered at their true size. A free pour of the inflated shells packs about as a
  free pour does, so the grains' own solid fraction is about ``phi_free / (1 - u)^3``:
  a smooth knob that can be steered.

**Control, and why a feedback rather than a calibration pour.** A calibration pour
costs a pour of its own at every size (the per-grain pour time must stay within 1.5x
of a free pour), and what a batch reaches depends on the bed it falls on. So the
pour steers itself: :class:`PackingController` measures, after each batch is locked,
the solid fraction of the new bulk layer (the region the pour's checks measure:
one median diameter from the wall and the floor, two below the pack top, and one
below the median height of the pack's surface, so a layer is measured once the grains
cover it and no later grain falls into it; for an interior crop, only the crop's footprint in it,
the part the pack shows, ``crop``); by Monte Carlo, :func:`synthpack.physics.checks.solid_fraction_of`:
points in a grain's hull count as its convexity, corrected by testing :data:`_EXACT_SAMPLES` of them
against the meshes, as shrunk shells let hulls overlap),
and sets the next batch's knob from a prior model of the fraction against the knob
(:class:`PackingPrior`; for ``u > 1``, the full compaction's fraction over the shrunk
shell's volume, ``(1 - shrink)^3``), scaled by the ratio measured so far (each layer against the
prior of the grains centred in it: a layer holds grains of several batches; shrunk toward 1 as by a
layer :data:`_PRIOR_HEIGHT` margins high at the prior, as a thin layer of a small crop measures
noisily), aiming the bulk still to come (the pack's surface scaled to all its grains) so that the
cumulative bulk fraction comes back to the target by the end of the pour (integral action, spread
over the rest of the pour rather than put on the next layer: one noisy layer of the sand micro-CT's
2x finer variant, 0.639 against 0.583, left three layers at 0.56, 0.47 and 0.53).
The first batches, before there is a bulk, use the prior alone. A target looser
than a free pour is never compacted (the knob stays <= 0): a batch the control would
compact pours freely instead. Which grains of a spaced batch collide bare, for a
target coordination, is :mod:`synthpack.physics.shells`' (``PackingController.bare``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import trimesh
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from .._shared.seeds import generator
from ..errors import SynthpackInputError
from .checks import BULK_FLOOR_MARGIN, BULK_TOP_MARGIN, PourChecks, bulk_shortfall, solid_fraction_of
from .container import crop_half_sides

logger = logging.getLogger(__name__)

__all__ = [
    "BatchCompaction",
    "MAX_TARGET",
    "PackingController",
    "PackingPrior",
    "TARGET_SOURCE",
    "TARGET_TOLERANCE",
    "expected_fraction",
    "parse_target",
    "report_target",
    "resolve_target",
]

#: ``pour.target_solid_fraction`` value that means "the source scan's bulk solid fraction".
TARGET_SOURCE = "source"
#: A target counts as reached when the bulk packing fraction is within this of it.
TARGET_TOLERANCE = 0.02
#: Friction coefficient of a batch while it settles at full compaction (u = 1).
SETTLE_FRICTION = 0.02
#: Steps a compacted batch falls at its lowered friction (at most).
FALL_STEPS = 4000
#: The low-friction fall ends when the batch moves slower than this times the settle thresholds.
FALL_QUIET = 8.0
#: Largest shell inflation, as a fraction of the grain's size (u = -MAX_INFLATION).
MAX_INFLATION = 0.6
#: Largest knob: full compaction with shells shrunk by the pour's ``max_shrink`` (an engine that shrinks shells).
MAX_KNOB = 2.0
#: Densest target accepted: random packings of rigid grains stay below it (spheres jam at
#: 0.64, ellipsoids at 0.74, the densest random packings known, of tetrahedra and cubes, at about 0.78).
MAX_TARGET = 0.8
#: Prior model (`PackingPrior`): packing fraction of the grains' convex hulls in a free pour and in a fully
#: compacted one, as measured: the `large` sample's grains (convexity 0.92) pack at 0.52 and 0.60, the sand
#: micro-CT's (0.81) at 0.52 under full compaction, both 0.65 of their hulls.
HULL_FREE, HULL_DENSE = 0.565, 0.65
#: The next layer aims at most this far from the target to make up for past layers (a target looser
#: than a free pour: this times target over the prior's free-pour fraction, the same share of the target).
_MAX_CORRECTION = 0.06
#: Above 1, a batch's knob rises at most this far above the last batch's (the shrunk layers' fraction is noisy).
_MAX_SHRINK_STEP = 0.5
#: After a compacted batch, the next batch's knob falls at most this far below its knob: thin layers measure
#: noisily (in the sand micro-CT's crop, 5 grains across, 0.51-0.64 a layer at a steady knob), and where the prior
#: is flat in the knob (0.5 to 1.5: 0.49 to 0.58 for sand) a full correction of one such layer swung the knob from
#: 1.59 to 0.57 and left two layers at 0.51. (0.5 kept short pours of the built-in samples from backing off an
#: overshoot in time.)
_MAX_KNOB_FALL = 0.75
#: The measured ratio to the prior is shrunk toward 1 as by a layer this many margins high at the prior: a thin
#: layer measures noisily (see _MAX_KNOB_FALL).
_PRIOR_HEIGHT = 1.0
_SAMPLES_PER_UNIT_VOLUME = 600  # Monte-Carlo points per cubic simulation unit of a layer
#: Of a layer's points, this many are tested against the meshes, to correct the cheap count of hull hits: shrunk
#: shells let hulls overlap, and other hulls fill a grain's concavities, so that count read a narrow tube of sand's
#: layers 0.010 above the meshes' fraction, and the pour stopped short of its target.
_EXACT_SAMPLES = 4000
_MIN_LAYER = 0.25  # thinner new bulk layers are measured with the next batch
_SURFACE_CELL = 0.5  # side of the columns the pack's surface height is taken in, in margins


def parse_source_number(
    value: Any, name: str, *, nones: tuple[str, ...], valid: Callable[[float], bool], expected: str,
) -> float | str | None:
    """A target given as ``"source"``, as None (or a word in `nones`, any case), or as a number `valid` accepts.

    The one parser of the pour's targets (`parse_target`, `~synthpack.physics.shells.parse_coordination`).

    Parameters
    ----------
    value : Any
        The setting as given (YAML, a CLI option, Python).
    name : str
        Its name, for the message.
    nones : tuple of str
        Words that mean None (``"none"``, ``"null"``, ...).
    valid : callable
        ``valid(number) -> bool`` for a finite number.
    expected : str
        What the message says the setting must be.

    Raises
    ------
    SynthpackInputError
        For anything else (booleans too).
    """
    if value is None or value == TARGET_SOURCE:
        return value
    if isinstance(value, str) and value.strip().lower() in nones:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if isinstance(value, bool) or not (math.isfinite(number) and valid(number)):
        raise SynthpackInputError(f"{name} must be {expected}; got {value!r}.")
    return number


def parse_target(value: Any, name: str = "target_solid_fraction") -> float | str | None:
    """A checked target: ``"source"``, a number in (0, :data:`MAX_TARGET`], or None (a free pour).

    Raises
    ------
    SynthpackInputError
        For anything else.
    """
    number = parse_source_number(value, name, nones=("none", "null", "free"), valid=lambda v: 0.0 < v < 1.0,
                                 expected="'source', a solid fraction in (0, 1) such as 0.55, or none for a free pour")
    if isinstance(number, float) and number > MAX_TARGET:
        raise SynthpackInputError(
            f"{name} {number:g} cannot be reached: no pour of rigid grains packs denser than about "
            f"{MAX_TARGET:g} (spheres 0.64); give at most {MAX_TARGET:g}, or 'source'."
        )
    return number


@dataclass(frozen=True)
class BatchCompaction:
    """What one batch gets before it is locked (simulation units).

    Attributes
    ----------
    knob : float
        ``u`` in ``[-MAX_INFLATION, MAX_KNOB]`` (see the module docstring).
    inflation : float
        Collision shells inflated by this fraction of the grain's size (0 for ``0 <= u <= 1``;
        negative, a shrunk shell, for ``u > 1``).
    settle_friction : float
        Friction coefficient of the batch while it falls (the material's for u <= 0).
    """

    knob: float
    inflation: float
    settle_friction: float

    @property
    def compacts(self) -> bool:
        """Whether the batch is compacted (falls at a lowered friction) rather than poured freely."""
        return self.knob > 0

    @classmethod
    def from_knob(cls, knob: float, friction: float, max_shrink: float = 0.0) -> BatchCompaction:
        """The batch's compaction for knob `knob`, the material's `friction` and the pour's `max_shrink`.

        Above 1 only with a `max_shrink` > 0 (the shell shrunk at ``u = MAX_KNOB``), else clipped to 1.
        """
        knob = float(np.clip(knob, -MAX_INFLATION, MAX_KNOB if max_shrink > 0 else 1.0))
        if knob <= 0.0:
            return cls(knob, -knob, friction)
        compacted = friction * (1.0 - min(knob, 1.0)) + min(SETTLE_FRICTION, friction) * min(knob, 1.0)
        return cls(knob, -_shrink(knob, max_shrink), compacted)


def _shrink(knob: float, max_shrink: float) -> float:
    """The fraction of their size the shells are shrunk by at knob `knob` (0 up to 1)."""
    return max(knob - 1.0, 0.0) * max_shrink


@dataclass(frozen=True)
class PackingPrior:
    """The prior model of the bulk packing fraction a batch reaches at knob ``u`` (before the measured correction).

    Grains collide as their convex hulls, so the prior is the hulls' packing fraction times the
    grains' convexity ``c`` (mean mesh volume over hull volume): :data:`HULL_FREE` for a free pour,
    rising linearly to :data:`HULL_DENSE` at full compaction (``u = 1``); divided by the shrunk
    shell's volume ``(1 - (u - 1) * max_shrink)^3`` above 1 and by the inflated shell's
    ``(1 - u)^3`` below 0.

    Attributes
    ----------
    convexity : float
        The grains' mean mesh volume over their convex hull's, in (0, 1].
    max_shrink : float
        The shells' shrink at knob :data:`MAX_KNOB`, a fraction of the grain's size (0: an engine
        that cannot shrink them).
    """

    convexity: float = 1.0
    max_shrink: float = 0.0

    @property
    def free(self) -> float:
        """The prior's packing fraction of a free pour (``u = 0``)."""
        return HULL_FREE * self.convexity

    @property
    def dense(self) -> float:
        """The prior's packing fraction under full compaction (``u = 1``)."""
        return HULL_DENSE * self.convexity

    def fraction(self, knob: float) -> float:
        """The packing fraction at knob `knob`."""
        if knob < 0:
            return self.free / (1.0 - knob) ** 3
        return (self.free + (self.dense - self.free) * min(knob, 1.0)) / (1.0 - _shrink(knob, self.max_shrink)) ** 3

    def knob(self, fraction: float, highest: float = 1.0) -> float:
        """The knob at which :meth:`fraction` is `fraction`, clipped to ``[-MAX_INFLATION, highest]``."""
        if fraction < self.free:
            return max(1.0 - (self.free / fraction) ** (1 / 3), -MAX_INFLATION)
        if fraction <= self.dense or highest <= 1.0 or self.max_shrink <= 0:
            return min((fraction - self.free) / (self.dense - self.free), 1.0)
        return min(1.0 + (1.0 - (self.dense / fraction) ** (1 / 3)) / self.max_shrink, highest)

    def full_compaction(self, heights: np.ndarray, fractions: np.ndarray, priors: np.ndarray) -> float:
        """What full compaction (``u = 1``) packs, predicted from compacted layers (heights, measured fractions
        and their :meth:`fraction` at their knobs, (L,) each): the prior's, scaled by their measured fraction over
        their prior (heights weighting both), so that a layer of any compacting knob counts."""
        return float(heights @ fractions / (heights @ priors)) * self.dense


@dataclass
class PackingController:
    """Steers each batch's knob toward a target bulk packing fraction (simulation units).

    The batch driver (:func:`synthpack.physics.driver.drive`, the same for every engine)
    asks :meth:`next_batch` before a batch falls and calls :meth:`observe`
    once it is locked; :meth:`record` is what the checks and the manifest keep.

    Parameters
    ----------
    target : float
        Target packing fraction of the bulk, in (0, 1).
    friction : float
        The material's friction coefficient (restored before locking).
    meshes : sequence of (vertices (V, 3) float, faces (F, 3) int)
        Each body's TRUE mesh in its local frame, simulation units (scaled), in
        pouring order: what is measured (and rendered).
    inner_radius : float
        The tube's inner radius, simulation units.
    margin : float
        Distance of the bulk from the floor (twice it below the top): one median
        grain diameter, i.e. 1 simulation unit.
    wall_margin : float
        Distance of the bulk from the wall, simulation units: `margin`, or more for
        the pour of an interior crop (`~synthpack.physics.container.CROP_WALL_MARGIN`).
    seed : int
        Seed of the Monte-Carlo points.
    bare : numpy.ndarray, optional
        (N,) bool: the bodies that collide without a spacing shell in a spaced batch
        (:func:`synthpack.physics.shells.bare_grains`); None: none does.
    shrinks : bool
        Whether the engine can shrink collision shells
        (:attr:`~synthpack.physics.engine.Engine.shrinks_shells`): then knobs above 1
        shrink them, by up to :attr:`max_shrink` (see the module docstring).
    crop : (float, float), optional
        For the pour of an interior crop: the ``(Y, X)`` extent the crop aims at, simulation
        units; the layers are measured in the crop's footprint in the bulk cylinder
        (`~synthpack.physics.container.crop_half_sides`), where the pack is shown (the middle of
        the tube packs denser than the cylinder's rim). None: the whole cylinder.
    """

    target: float
    friction: float
    meshes: Sequence[tuple[np.ndarray, np.ndarray]]
    inner_radius: float
    margin: float = 1.0
    wall_margin: float = 1.0
    seed: int = 0
    bare: np.ndarray | None = None
    shrinks: bool = False
    crop: tuple[float, float] | None = None
    #: The knob of every batch so far.
    knobs: list[float] = field(default_factory=list)
    #: Measured bulk layers: (z0, z1, packing fraction, knob of its grains: the one whose prior fraction is
    #: the mean of theirs, volume-weighted, for the grains centred in it; else of the batch that completed it).
    layers: list[tuple[float, float, float, float]] = field(default_factory=list)
    #: Set once every bulk layer measured so far held no solid: the control could not steer (see :meth:`next_batch`).
    degenerate: bool = False
    #: Set once the prior, or the compacted layers once measured, say full compaction packs short of the target:
    #: knobs may then exceed 1 (shrunk shells).
    shrinking: bool = False
    _grains: dict[int, tuple] = field(default_factory=dict, repr=False)
    _knob_of: dict[int, tuple[float, float]] = field(default_factory=dict, repr=False)  # body -> (knob, volume)
    # the figures of each distinct mesh (bytes of its vertices and faces): a pour repeats its library's grains
    _figures_of: dict[tuple[bytes, bytes], _MeshFigures] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self._measured_to = BULK_FLOOR_MARGIN * float(self.margin)  # the bulk region's floor
        self._rng = generator(self.seed, "compaction")
        convexity = float(np.mean([self._figures(v, f).convexity for v, f in self.meshes]))
        #: The shells' shrink at knob MAX_KNOB: ``1 - c^(1/3)``, ``c`` the grains' mean mesh over hull volume.
        self.max_shrink = 1.0 - convexity ** (1 / 3) if self.shrinks else 0.0
        #: The prior model of the fraction against the knob, for these grains.
        self.prior = PackingPrior(convexity, self.max_shrink)
        # the grains observed so far, in observing order: their keys and lowest, highest and mean z
        self._observed: list[int] = []
        self._z = np.empty((len(self.meshes), 3))  # rows 0 .. len(self._observed) - 1 in use
        self._top = -math.inf
        self._surface: np.ndarray | None = None  # highest grain point over each column (`_surface_height`)

    def _figures(self, vertices: np.ndarray, faces: np.ndarray) -> _MeshFigures:
        """`_MeshFigures` of a mesh, computed once for each distinct one."""
        key = (np.ascontiguousarray(vertices).tobytes(), np.ascontiguousarray(faces).tobytes())
        if key not in self._figures_of:
            self._figures_of[key] = _MeshFigures.of(vertices, faces)
        return self._figures_of[key]

    def next_batch(self) -> BatchCompaction:
        """The knob of the next batch, from the target, the layers measured so far and the prior.

        Layers whose measured fraction is not a positive number (no grain reached the
        measured region) say nothing of how the knob works: they are left out. When
        every layer so far is such, the control stops steering (:attr:`degenerate`,
        logged as a warning once) and the batch gets the prior's knob for the target,
        until a layer holds solid.
        """
        measured = [(z1 - z0, f, k) for z0, z1, f, k in self.layers if math.isfinite(f) and f > 0]
        wanted, ratio = self.target, 1.0
        if self.layers and not measured and not self.degenerate:
            self.degenerate = True
            logger.warning("Target packing fraction %.3f: the bulk layers measured so far hold no solid, so the "
                           "pour cannot be steered: batches get the prior model's knob until one does.", self.target)
        if measured:
            heights, fractions, knobs = (np.array(column) for column in zip(*measured))
            priors = np.array([self.prior.fraction(k) for k in knobs])
            reached = float(heights @ fractions / heights.sum())
            # the measured ratio to the prior, shrunk toward 1 by a pseudo-layer of _PRIOR_HEIGHT margins at the prior
            pseudo = _PRIOR_HEIGHT * self.margin * float(heights @ priors / heights.sum())
            ratio = float((heights @ fractions + pseudo) / (heights @ priors + pseudo))
            compacted = knobs > 0  # shells shrink once the compacted layers say full compaction falls short
            if compacted.any():
                self._shrink_if_short(self.prior.full_compaction(heights[compacted], fractions[compacted],
                                                                 priors[compacted]), "the compacted layers")
            # aim the rest of the bulk so the cumulative fraction returns to the target by the end of the pour
            wanted = self.target + (self.target - reached) * heights.sum() / self._bulk_left(heights)
            correction = _MAX_CORRECTION * min(1.0, self.target / self.prior.free)
            wanted = float(np.clip(wanted, self.target - correction, self.target + correction))
        elif not self.knobs:
            self._shrink_if_short(self.prior.dense, "the prior")
        knob = self.prior.knob(wanted / ratio, MAX_KNOB if self.shrinking else 1.0)
        if knob > 1.0:
            knob = min(knob, max(self.knobs[-1] if self.knobs else 1.0, 1.0) + _MAX_SHRINK_STEP)
        if self.knobs and self.knobs[-1] > 0:  # after a compacted batch the knob falls by at most _MAX_KNOB_FALL
            knob = max(knob, self.knobs[-1] - _MAX_KNOB_FALL)
        if self.target < self.prior.free:
            knob = min(knob, 0.0)  # looser than a free pour: spaced or free, never compacted
        self.knobs.append(knob)
        return BatchCompaction.from_knob(knob, self.friction, self.max_shrink)

    def observe(self, members: np.ndarray, positions: np.ndarray, quaternions: np.ndarray) -> None:
        """Take a locked batch's final poses and measure the bulk layer it completed.

        Parameters
        ----------
        members : numpy.ndarray
            (M,) int indices of the batch's bodies (into `meshes`).
        positions, quaternions : numpy.ndarray
            (M, 3) local-origin positions and (M, 4) (w, x, y, z) orientations.
        """
        radius = self.inner_radius - self.wall_margin
        for k, position, quaternion in zip(members, positions, quaternions):
            vertices, faces = self.meshes[k]
            figures = self._figures(vertices, faces)
            rotation = Rotation.from_quat(quaternion, scalar_first=True)
            world = rotation.apply(vertices) + position
            if int(k) in self._grains:
                raise ValueError(f"body {int(k)} was observed before")
            self._grains[int(k)] = (vertices, faces, figures.equations, np.asarray(position, dtype=float),
                                    rotation, 1.0, world, figures.convexity)
            self._knob_of[int(k)] = (self.knobs[-1], figures.volume)
            heights = world[:, 2]
            self._z[len(self._observed)] = heights.min(), heights.max(), heights.mean()
            self._observed.append(int(k))
            self._top = max(self._top, float(heights.max()))
            if radius > 0:
                self._raise_surface(world, radius)
        if radius <= 0:
            return
        z0 = self._measured_to
        z1 = min(self._top - BULK_TOP_MARGIN * self.margin, self._surface_height(radius) - self.margin)
        if z1 - z0 < _MIN_LAYER:
            return
        low, high = self._z[:len(self._observed), 0], self._z[:len(self._observed), 1]
        grains = [self._grains[self._observed[i]] for i in np.flatnonzero((high >= z0) & (low <= z1))]
        half = None if self.crop is None else crop_half_sides(radius, self.crop)
        area = np.pi * radius**2 if half is None else 4.0 * float(half[0] * half[1])
        n_samples = max(500, int(_SAMPLES_PER_UNIT_VOLUME * area * (z1 - z0)))
        fraction = solid_fraction_of(grains, radius, z0, z1, n_samples, self._rng, n_exact=_EXACT_SAMPLES,
                                     half_sides=half)
        knob = self._layer_knob(z0, z1)
        self.layers.append((z0, z1, fraction, knob))
        self._measured_to = z1
        logger.debug("Bulk layer %.2f..%.2f: packing fraction %.3f (knob %.3f)", z0, z1, fraction, knob)

    def _bulk_left(self, heights: np.ndarray) -> float:
        """The bulk height still to come above the measured layers (of `heights`), at least their mean: the
        pack's surface so far scaled to all the grains, less the margin and the measured bulk."""
        radius = self.inner_radius - self.wall_margin
        final = self._surface_height(radius) * len(self.meshes) / max(len(self._observed), 1) - self.margin
        return max(final - self._measured_to, float(heights.mean()))

    def _layer_knob(self, z0: float, z1: float) -> float:
        """The knob of the grains centred in ``z0 <= z < z1``: a layer holds grains of several batches.

        The knob whose prior fraction is the volume-weighted mean of theirs, so the measured
        ratio to the prior compares like with like; the last batch's where none is centred there.
        """
        middle = self._z[:len(self._observed), 2]
        centred = (middle >= z0) & (middle < z1)
        placed = [self._knob_of[self._observed[i]] for i in np.flatnonzero(centred)]
        if not placed:
            return self.knobs[-1]
        knobs, volumes = (np.array(column) for column in zip(*placed))
        if np.ptp(knobs) == 0:
            return float(knobs[0])
        return self.prior.knob(float(volumes @ [self.prior.fraction(k) for k in knobs] / volumes.sum()),
                               MAX_KNOB if self.shrinking else 1.0)

    def _shrink_if_short(self, full: float, says: str) -> None:
        """Let knobs exceed 1 (:attr:`shrinking`) where full compaction, predicted to pack at `full` by `says`,
        falls short of the target by more than half its tolerance, with an engine that shrinks shells."""
        if self.max_shrink > 0 and not self.shrinking and full < self.target - TARGET_TOLERANCE / 2:
            self.shrinking = True
            logger.debug("Full compaction packs at %.3f (%s), below %.3f: shells shrink by up to %.3f", full, says,
                         self.target, self.max_shrink)

    def _surface_height(self, radius: float) -> float:
        """Median height of the pack's surface within `radius` of the axis (0 where the floor shows).

        The surface is the highest grain point over each column of :data:`_SURFACE_CELL`
        margins across (the grains' true mesh vertices), 0 in a column no grain covers.
        """
        if self._surface is None:
            return 0.0
        n, cell = len(self._surface) // 2, _SURFACE_CELL * self.margin
        centres = (np.arange(2 * n) - n + 0.5) * cell
        inside = np.hypot(centres[:, None], centres[None, :]) <= radius
        return float(np.median(self._surface[inside])) if inside.any() else 0.0

    def _raise_surface(self, world: np.ndarray, radius: float) -> None:
        """Raise the columns of `_surface_height`'s surface (``(2n, 2n)``, 0 where no grain is) that the
        world vertices (V, 3) of one more grain reach above it."""
        cell = _SURFACE_CELL * self.margin
        n = max(1, int(np.ceil(radius / cell)))
        if self._surface is None:
            self._surface = np.zeros((2 * n, 2 * n))
        columns = np.clip(np.floor(world[:, :2] / cell).astype(np.int64) + n, 0, 2 * n - 1)
        np.maximum.at(self._surface, (columns[:, 0], columns[:, 1]), world[:, 2])

    def record(self) -> dict[str, Any]:
        """The knob of every batch, the measured bulk layers and the number of bare grains, JSON-able; the
        shells' largest shrink (``max_shrink``, at knob `MAX_KNOB`) where knobs above 1 were allowed."""
        record: dict[str, Any] = {
            "knobs": [round(k, 4) for k in self.knobs],
            "layers": [{"z0": z0, "z1": z1, "packing_fraction": f, "knob": round(k, 4)}
                       for z0, z1, f, k in self.layers],
        }
        if self.bare is not None:
            record["bare_grains"] = int(np.count_nonzero(self.bare))
        if self.shrinking:
            record["max_shrink"] = round(self.max_shrink, 4)
        return record


@dataclass(frozen=True)
class _MeshFigures:
    """What the controller measures with of one mesh: its convex hull's half-spaces ``(H, 4)``
    (`scipy.spatial.ConvexHull.equations`), its volume, and that over its hull's (1 for a convex grain)."""

    equations: np.ndarray
    volume: float
    convexity: float

    @classmethod
    def of(cls, vertices: np.ndarray, faces: np.ndarray) -> _MeshFigures:
        hull = ConvexHull(vertices)
        volume = float(trimesh.Trimesh(vertices, faces, process=False).volume)
        return cls(hull.equations, volume, volume / hull.volume)


def resolve_target(target: Any, library: Any, engine: Any) -> float | None:
    """The target packing fraction a pour aims at, or None for a free pour.

    Parameters
    ----------
    target : "source", float or None
        ``pour.target_solid_fraction`` (see :func:`parse_target`).
    library : ParticleLibrary
        Its ``statistics.solid_fraction`` is the source's bulk solid fraction.
    engine : Engine
        The engine; one that does not ``supports_compaction`` pours freely for
        ``"source"`` (with a logged note) and refuses a number.

    Raises
    ------
    SynthpackInputError
        For a bad target, or a number with an engine that cannot pack to it.
    """
    target = parse_target(target)
    if target is None:
        return None
    if not engine.supports_compaction:
        if target == TARGET_SOURCE:
            logger.info("The %s engine does not pack to a target solid fraction: a free pour "
                        "(target_solid_fraction 'source' is ignored).", engine.name)
            return None
        raise SynthpackInputError(
            f"The {engine.name} engine cannot pack to target_solid_fraction {target:g}; "
            "use another engine, or target_solid_fraction: none."
        )
    if target == TARGET_SOURCE:
        statistics = getattr(library, "statistics", None)
        measured = getattr(statistics, "solid_fraction", None)
        if measured is None:
            logger.info("The library holds no source solid fraction: a free pour.")
            return None
        return float(measured)
    return float(target)


def report_target(checks: PourChecks, target: float | None, controller: PackingController | None) -> PourChecks:
    """`checks` with the target, whether the bulk reached it, and the controller's record.

    A target missed by more than :data:`TARGET_TOLERANCE` is logged as a warning that
    says which way and why (too dense for the shapes, or too loose for the largest
    spacing), and ``checks.target_reached`` is False. A pack too shallow or narrow for
    a bulk region cannot be measured: ``target_reached`` stays None (unknown) and a
    warning says so, with about how many grains in this tube would give a bulk.
    """
    if target is None:
        return checks
    checks.target_packing_fraction = float(target)
    checks.compaction = None if controller is None else controller.record()
    reached = checks.packing_fraction
    if math.isnan(reached):
        n_grains = None if controller is None else len(controller.meshes)
        logger.warning("target %.3f not judged (%s)", target,
                       bulk_shortfall(checks.packing_region, n_grains))
        return checks
    checks.target_reached = bool(abs(reached - target) <= TARGET_TOLERANCE)
    if not checks.target_reached:
        limit = (MAX_KNOB if controller is not None and controller.max_shrink > 0 else 1.0) \
            if reached < target else -MAX_INFLATION
        knobs = [] if controller is None else controller.knobs
        if controller is not None and controller.degenerate and not any(f > 0 for _, _, f, _ in controller.layers):
            why = "the bulk layers measured while pouring held no solid, so the pour was not steered"
        elif knobs and np.mean(np.isclose(knobs, limit)) >= 0.5:
            why = ("denser than these grains pack under full compaction" if reached < target
                   else "looser than the largest spacing gives")
        else:
            why = "the control did not settle in so few batches: pour more grains or smaller batches"
        logger.warning("Target packing fraction %.3f NOT reached: the bulk packs at %.3f (%s).",
                       target, reached, why)
    else:
        logger.info("Target packing fraction %.3f reached: the bulk packs at %.3f.", target, reached)
    return checks


def expected_fraction(target: Any, library: Any, default: float) -> float:
    """The packing fraction to size a tube for: `default`, or a looser target (so a spaced pack fits).

    Parameters
    ----------
    target : "source", float or None
        ``pour.target_solid_fraction``.
    library : ParticleLibrary
        For ``"source"``: its ``statistics.solid_fraction``.
    default : float
        The tube's usual expected packing fraction.
    """
    target = parse_target(target)
    if target == TARGET_SOURCE:
        target = getattr(getattr(library, "statistics", None), "solid_fraction", None)
    return default if target is None else min(float(target), default)
