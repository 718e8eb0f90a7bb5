"""Grain collision hulls, the same for every engine.

Both engines collide a grain as its convex hull, simplified when it has many
vertices: contact cost grows with the vertex count (measured with pybullet: about
1.5x faster per step at 64 vertices than with the ~170-vertex hulls of 500-face
grains), and for grains of ~20 voxels across the 64-vertex hull stays within about
0.4 voxel of the true hull.
"""

from __future__ import annotations

import numpy as np
import trimesh

__all__ = ["MAX_HULL_VERTICES", "convex_hull", "simplify_hull"]

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
