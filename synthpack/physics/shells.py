"""Spacing shells for a target coordination: which grains of a spaced pour collide bare, the others' shells.

A pour looser than a free pour spaces its grains with collision shells
(:mod:`synthpack.physics.compaction`: every grain inflated by ``-u`` of its size), so
no two grains touch: aggregates floating in cement paste (solid fraction 0.25) touch
now and then (the concrete scan: 1.05 contacts per grain), a spaced pack of equal
shells never (0.5 contacts per grain, the few grains whose rendered voxels meet across
the shell's gap). ``pour.target_coordination`` asks for a mean coordination number
``C`` (contacts per grain; ``"source"``: the source scan's, ``SourceStatistics.coordination``):

* a fraction ``b`` of the grains of each batch, chosen once per pour from the ``"shells"``
  random stream, collides **bare** (its true hull). Two bare grains touch where they rest on
  each other; a bare grain and a shelled one stay the shell's width apart. A bare grain
  has a few neighbours, about ``b`` of them bare, so the pack has about
  ``C = BARE_CONTACTS * b^2`` contacts per grain: ``b = sqrt(C / BARE_CONTACTS)``, at most
  :data:`MAX_BARE` (a pour with more bare grains is a free pour, not spaced).
  :data:`BARE_CONTACTS` is measured, as ``C / b^2`` on the rendered labels of spaced packs
  of the built-in samples (``large`` and ``small``, targets 0.25-0.30, 150-300 grains):
  3.0-3.4 in six packs of seven (median 3.2), below a free pour's coordination (5.0 for
  the concrete scan's aggregates) because a bare grain is smaller than its shelled
  neighbours, so it touches fewer of them and a smaller share of those are bare. Those
  grains were drawn evenly, as a scan in a container gives them (the concrete scan's); the
  `large` sample drawn by its window weights (`synthpack.library.sampling`: larger grains
  more often) gives 4.0-4.7 (three seeds, target 1.0: 1.25-1.47 contacts per grain), so
  there the prior overshoots;
* the other grains of each batch get shells thick enough that the batch's mean
  collision volume stays that of the knob's equal shells (:func:`shell_inflations`),
  so the solid fraction the knob steers (and its prior model) holds.

Only spaced batches (knob ``u < 0``) have shells; a compacted or free batch is bare
whatever the target coordination.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from .._shared.seeds import generator
from .compaction import TARGET_SOURCE, parse_source_number

logger = logging.getLogger(__name__)

__all__ = [
    "BARE_CONTACTS",
    "MAX_BARE",
    "bare_fraction",
    "bare_grains",
    "parse_coordination",
    "resolve_coordination",
    "shell_inflations",
]

#: Contacts per grain of a spaced pack per squared share of bare grains (face contacts of its rendered labels in
#: the bulk; measured on the built-in samples, see the module docstring): the prior of :func:`bare_fraction`.
BARE_CONTACTS = 3.2
#: The largest fraction of bare grains.
MAX_BARE = 0.8


def parse_coordination(value: Any, name: str = "target_coordination") -> float | str | None:
    """A checked target coordination: ``"source"``, a number >= 0 (contacts per grain), or None (equal shells).

    Raises
    ------
    SynthpackInputError
        For anything else.
    """
    return parse_source_number(
        value, name, nones=("none", "null"), valid=lambda v: v >= 0.0,
        expected="'source', a mean number of contacts per grain >= 0 such as 1.0, or none "
                 "(every grain of a spaced pour in an equal shell)",
    )


def resolve_coordination(value: Any, library: Any) -> float | None:
    """The mean coordination a spaced pour aims at, or None (equal shells, no grain bare).

    Parameters
    ----------
    value : "source", float or None
        ``pour.target_coordination`` (see :func:`parse_coordination`).
    library : ParticleLibrary
        For ``"source"``: its ``statistics.coordination`` (None, with a logged note,
        for a library that holds none).
    """
    value = parse_coordination(value)
    if value != TARGET_SOURCE:
        return value
    measured = getattr(getattr(library, "statistics", None), "coordination", None)
    if measured is None:
        logger.info("The library holds no source coordination: a spaced pour gives every grain an equal shell.")
        return None
    return float(measured)


def bare_fraction(coordination: float | None) -> float:
    """The fraction of bare grains for a target mean `coordination` (see the module docstring); 0 for None."""
    if coordination is None:
        return 0.0
    return min(math.sqrt(max(float(coordination), 0.0) / BARE_CONTACTS), MAX_BARE)


def bare_grains(batches: np.ndarray, fraction: float, seed: int) -> np.ndarray | None:
    """Which of a pour's grains collide bare: in each batch, the nearest whole number to `fraction` of its grains.

    Parameters
    ----------
    batches : numpy.ndarray
        (N,) int, the batch of each grain, in pouring order.
    fraction : float
        The share of bare grains, in [0, 1].
    seed : int
        The pour's seed: the grains are chosen at random from its ``"shells"`` stream, so the
        other draws of a pour stay as they were.

    Returns
    -------
    numpy.ndarray or None
        (N,) bool; None when `fraction` is 0. A fixed count per batch rather than a draw per
        grain: the coordination follows the share of bare grains, and a binomial draw would
        move it by 10% in a pour of 300.
    """
    if fraction <= 0:
        return None
    batches = np.asarray(batches)
    draws = generator(seed, "shells").random(len(batches))
    bare = np.zeros(len(batches), dtype=bool)
    for batch in np.unique(batches):
        members = np.flatnonzero(batches == batch)
        bare[members[np.argsort(draws[members])[:int(round(fraction * len(members)))]]] = True
    return bare


def shell_inflations(inflation: float, bare: np.ndarray) -> np.ndarray:
    """Each grain's shell inflation in a batch whose equal shells would be `inflation`.

    Parameters
    ----------
    inflation : float
        The knob's inflation (:class:`~synthpack.physics.compaction.BatchCompaction`); < 0
        (shells shrunk past full compaction) applies to every grain, bare or not.
    bare : numpy.ndarray
        (M,) bool, the batch's bare grains.

    Returns
    -------
    numpy.ndarray
        (M,) float64: 0 for the bare grains, and for the others the inflation ``s`` with
        ``(1 - f) (1 + s)^3 + f = (1 + inflation)^3`` (``f`` the batch's bare fraction),
        so the batch's mean collision volume is that of the equal shells: `inflation`
        itself where no grain is bare or ``inflation <= 0``, all 0 for a batch of bare grains only.
    """
    bare = np.asarray(bare, dtype=bool)
    if inflation <= 0 or not bare.any():  # a free batch, shrunk shells (past full compaction) or no bare grain
        return np.full(len(bare), float(inflation))
    if bare.all():
        return np.zeros(len(bare))
    f = float(bare.mean())
    thick = (((1.0 + inflation) ** 3 - f) / (1.0 - f)) ** (1 / 3) - 1.0
    return np.where(bare, 0.0, thick)
