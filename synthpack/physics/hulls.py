"""Grain collision hulls, the same for every engine.

Both engines collide a grain as its convex hull, simplified when it has many
vertices: contact cost grows with the vertex count (measured with pybullet: about
1.5x faster per step at 64 vertices than with the ~170-vertex hulls of 500-face
grains), and for grains of ~20 voxels across the 64-vertex hull stays within about
0.4 voxel of the true hull (on either side of it: :func:`protrusion` measures how far
a grain reaches outside its collision shape, which the pybullet engine's tube allows
for). :func:`shrink_hull` takes a collision margin off a hull.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

__all__ = ["MAX_HULL_VERTICES", "convex_hull", "simplify_hull", "shrink_hull", "protrusion"]

#: Default cap on the vertices of a grain's collision hull.
MAX_HULL_VERTICES = 64


def convex_hull(vertices: np.ndarray) -> trimesh.Trimesh:
    """The convex hull of a grain's vertices.

    Parameters
    ----------
    vertices : (V, 3) ndarray
        Mesh vertices, any length unit.

    Returns
    -------
    trimesh.Trimesh
        The hull; its vertices are those of `vertices` on the hull, in their order.
    """
    return trimesh.convex.convex_hull(np.asarray(vertices, dtype=np.float64))


def simplify_hull(hull: trimesh.Trimesh, max_vertices: int | None) -> trimesh.Trimesh:
    """A convex hull simplified by quadric decimation to at most `max_vertices` vertices.

    The decimation starts from the hull of the hull's own vertices (so qhull numbers
    its facets from those points alone); a closed triangulated convex polyhedron with
    V vertices has 2 V - 4 faces.

    Parameters
    ----------
    hull : trimesh.Trimesh
        A convex hull, e.g. from :func:`convex_hull`.
    max_vertices : int or None
        Largest number of vertices kept (>= 8); None keeps the hull as it is.

    Returns
    -------
    trimesh.Trimesh
        `hull` itself when it has at most `max_vertices` vertices, else the convex
        hull of its decimation.
    """
    if max_vertices is None or len(hull.vertices) <= max_vertices:
        return hull
    rehulled = trimesh.convex.convex_hull(np.asarray(hull.vertices))
    return rehulled.simplify_quadric_decimation(face_count=2 * max_vertices - 4).convex_hull


def shrink_hull(hull: trimesh.Trimesh, distance: float) -> np.ndarray:
    """Vertices of `hull` with every face moved `distance` inwards (its inner parallel body).

    Bullet collides a convex hull shape as the hull dilated by its collision margin (a
    Minkowski sum with a ball: measured, a unit cube of margin m rests at height
    0.5 + m), so grains that touch in the simulation stay ``2 m`` apart. A hull shrunk
    by the margin dilates back onto itself. Each vertex moves to the point that lies
    `distance` inside all of its incident face planes (least squares where more than
    three meet), so the vertex count and the faces' normals are kept.

    Parameters
    ----------
    hull : trimesh.Trimesh
        A convex hull (:func:`convex_hull` or :func:`simplify_hull`), any length unit.
    distance : float
        How far to move each face inwards, same unit (>= 0, small against the hull).

    Returns
    -------
    (V, 3) ndarray of float64
        The moved vertices, in the order of ``hull.vertices``.
    """
    vertices = np.asarray(hull.vertices, dtype=np.float64)
    if distance <= 0:
        return vertices.copy()
    normals = np.asarray(hull.face_normals, dtype=np.float64)
    moved = np.empty_like(vertices)
    for k, incident in enumerate(hull.vertex_faces):
        n = normals[incident[incident >= 0]]
        step = np.linalg.lstsq(n, np.full(len(n), -distance), rcond=1e-3)[0]
        length = float(np.linalg.norm(step))
        if length > 4 * distance:  # a needle-sharp vertex: keep the shape, move it 4 margins at most
            step *= 4 * distance / length
        moved[k] = vertices[k] + step
    return moved


def protrusion(points: np.ndarray, parts: Sequence[np.ndarray]) -> float:
    """How far `points` reach outside the union of convex `parts` (0 if all are inside one).

    Parameters
    ----------
    points : (M, 3) ndarray
        Points, e.g. a grain's mesh vertices.
    parts : sequence of (P, 3) ndarray
        Vertices of each convex part (e.g. a collision hull, or the parts of a convex
        decomposition), same frame and unit.

    Returns
    -------
    float
        The largest, over the points, of the smallest over the parts of the point's
        largest signed distance to a face plane of the part: for a point outside every
        part, a lower bound on its distance to the union (exact off the parts' faces).
    """
    points = np.asarray(points, dtype=np.float64)
    outside = np.full(len(points), np.inf)
    for part in parts:
        planes = ConvexHull(np.asarray(part, dtype=np.float64)).equations
        outside = np.minimum(outside, (points @ planes[:, :3].T + planes[:, 3]).max(axis=1))
    return max(0.0, float(outside.max()))
