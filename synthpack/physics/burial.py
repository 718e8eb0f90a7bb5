"""Which locked grains are buried too deep for any later grain to touch them.

Every grain still in a physics world costs a little per step, even a static one
(measured with pybullet: 4,000 locked grains made a step of 50 falling grains 3-6x
slower), so both engines remove locked grains that can no longer be reached, after
their final poses are recorded; the cost per grain then stays about flat however
many grains are poured.

This module needs only NumPy (1.x or 2.x) and imports nothing from synthpack:
``blender_script.py``, which runs inside Blender's own Python, loads it by file path.
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
    in it, and a column without any counts as the floor (z = 0), so nothing is buried
    until the whole cross-section is covered. A grain whose top lies more than two of
    the largest grain diameters below the LOWEST column is covered everywhere by a
    thick layer of locked grains.

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
    points = np.concatenate(list(hulls))
    ix = np.clip(np.floor(points[:, 0]).astype(np.int64) + half, 0, 2 * half - 1)
    iy = np.clip(np.floor(points[:, 1]).astype(np.int64) + half, 0, 2 * half - 1)
    heights = np.zeros(cx.shape)
    np.maximum.at(heights, (ix, iy), points[:, 2])
    cut = float(heights[inside].min()) - 2 * largest
    return np.array([hull[:, 2].max() < cut for hull in hulls], dtype=bool)
