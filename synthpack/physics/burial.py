"""Which locked grains are buried too deep for any later grain to touch them.

Every grain still in a physics world costs a little per step, even a static one
(measured with pybullet: 4,000 locked grains made a step of 50 falling grains 3-6x
slower), so the batch driver (:mod:`synthpack.physics.driver`) has every engine remove
the locked grains that can no longer be reached, after their final poses are recorded;
the cost per grain then stays about flat however many grains are poured.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

__all__ = ["largest_diameter", "buried"]


def largest_diameter(vertex_sets: Iterable[np.ndarray]) -> float:
    """Twice the largest distance of any vertex from its grain's local origin.

    Parameters
    ----------
    vertex_sets : iterable of (V, 3) ndarray
        Each grain's vertices in its local frame.

    Returns
    -------
    float
        An upper bound on the diameter of every grain, same unit as the vertices.
    """
    return 2 * max(float(np.linalg.norm(v, axis=1).max()) for v in vertex_sets)


def buried(hulls: Sequence[np.ndarray], radius: float, largest: float) -> np.ndarray:
    """Which locked grains lie too deep for any later grain to reach them.

    The pack's surface is sampled on a square grid of one-unit (about one grain)
    columns inside the tube: each column's height is the highest locked hull vertex
    in it, and a column without any counts as the floor (z = 0). A later grain comes
    down in some column and reaches at most about one largest diameter sideways, so
    each grain is judged against the LOWEST column within ``ceil(largest) + 1`` columns
    of those its hull covers (its local surface): a grain whose top lies more than two
    of the largest grain diameters below that is covered everywhere a later grain could
    reach it from by a thick layer of locked grains. Until 0.5 the lowest column of the
    whole tube was used, which in a tube many grains wide kept every grain in the world
    while any hole remained anywhere in the top layer.

    Parameters
    ----------
    hulls : sequence of (H, 3) ndarray
        World coordinates of each locked grain's hull vertices, simulation units
        (about one grain diameter); the tube's axis is the z axis.
    radius : float
        Inner radius of the tube.
    largest : float
        Largest grain diameter (:func:`largest_diameter`).

    Returns
    -------
    (N,) ndarray of bool
        True for each grain of `hulls` that is buried.
    """
    half = int(np.ceil(radius))
    centres = np.arange(-half, half) + 0.5
    cx, cy = np.meshgrid(centres, centres, indexing="ij")
    inside = np.hypot(cx, cy) <= radius - 0.5
    if len(hulls) == 0 or not inside.any():
        return np.zeros(len(hulls), dtype=bool)
    columns = [(_column(hull[:, 0], half), _column(hull[:, 1], half)) for hull in hulls]
    heights = np.zeros(cx.shape)
    for hull, (ix, iy) in zip(hulls, columns):
        np.maximum.at(heights, (ix, iy), hull[:, 2])
    reach = int(np.ceil(largest)) + 1
    surface = np.pad(np.where(inside, heights, np.inf), reach, constant_values=np.inf)
    lowest = np.lib.stride_tricks.sliding_window_view(surface, (2 * reach + 1,) * 2).min(axis=(2, 3))
    cuts = np.array([lowest[ix.min():ix.max() + 1, iy.min():iy.max() + 1].min() for ix, iy in columns])
    tops = np.array([float(hull[:, 2].max()) for hull in hulls])
    return tops < cuts - 2 * largest


def _column(coordinates: np.ndarray, half: int) -> np.ndarray:
    """Grid column index (0 .. 2 half - 1) of each coordinate, clipped to the grid."""
    return np.clip(np.floor(coordinates).astype(np.int64) + half, 0, 2 * half - 1)
