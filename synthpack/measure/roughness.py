"""Boundary roughness of grain sections: how much longer a section's outline is than its smoothed outline.

A grain cut by a slice shows a section; a real grain's section has a smooth outline
(as smooth as the pixels allow), a grain rendered from a voxel staircase shows teeth
where the cut runs obliquely through the staircase. The *roughness* of a section is

    roughness = L(section) / L(smoothed section),

with ``L`` the length of the marching-squares contour (pixels; at level 0.5 of the
binary section, at the area-preserving level of the smoothed one: the level above
which the smoothed section holds exactly as many pixels as the section, so the smooth
outline is neither shrunk nor grown), and the smoothed section the section convolved
with a Gaussian of `SIGMA` pixels. A digitised disc scores about 1.05 (the outline's
pixel corners), an outline with teeth one or two pixels wide much more (a comb of
them: 2 and above). The figure compares a pack with its source, so what the
digitisation adds cancels.

`section_roughness` measures one section, `slice_roughness` every section of one
labelled slice, `volume_roughness` the sections of evenly spaced slices of a volume.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["MIN_AREA", "SIGMA", "SLICES", "contour_length", "section_roughness", "slice_roughness",
           "volume_roughness"]

#: Smoothing of the section that gives the smooth outline, pixels (Gaussian standard deviation).
SIGMA = 1.5
#: Sections of fewer pixels are not measured: their outline is mostly pixel corners.
MIN_AREA = 30
#: Slices `volume_roughness` measures by default, evenly spaced.
SLICES = 24


def contour_length(image: np.ndarray, level: float) -> float:
    """Length of the marching-squares iso-contour of `image` at `level` (pixels).

    Parameters
    ----------
    image : ndarray of float, shape (H, W)
        Values at pixel centres; contours are closed where `image` is below `level` on its border.
    level : float

    Returns
    -------
    float
        Total length of every contour (pixels), 0 when none crosses `level`.
    """
    _, lengths = _cell_lengths(np.asarray(image, dtype=np.float64) - level)
    return float(lengths.sum())


def _cell_lengths(v: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
    """The marching-squares contour of `v` (H, W) at 0, cell by cell: the crossed cells and their segments' length.

    In each 2x2 cell of pixel centres, the points where its edges (linearly
    interpolated) cross 0 are joined two by two; a saddle cell (four crossings) joins
    them as the sign of its centre (the mean of its corners) separates its corners.
    Returns the (row, column) indices of the cells' top-left pixels, each (K,), and the
    lengths (K,), pixels.
    """
    corners = np.stack([v[:-1, :-1], v[:-1, 1:], v[1:, 1:], v[1:, :-1]])  # a, b, c, d: clockwise from top left
    above = corners > 0
    cells = np.nonzero(above.any(axis=0) & ~above.all(axis=0))
    corners, above = corners[:, cells[0], cells[1]], above[:, cells[0], cells[1]]  # (4, K): the crossed cells
    # edges top (a, b), right (b, c), bottom (d, c), left (a, d), and where each is crossed (row, column in the cell)
    p, q = corners[[0, 1, 3, 0]], corners[[1, 2, 2, 3]]
    crossed = above[[0, 1, 3, 0]] != above[[1, 2, 2, 3]]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(crossed, p / (p - q), 0.0)
    zero, one = np.zeros_like(t[0]), np.ones_like(t[0])
    points = np.stack([np.stack([zero, t[1], one, t[3]]), np.stack([t[0], one, t[2], zero])], axis=-1)  # (4, K, 2)
    index = np.arange(points.shape[1])

    def segment(first: np.ndarray | int, second: np.ndarray | int) -> np.ndarray:
        return np.hypot(*(points[first, index] - points[second, index]).T)

    # two crossings: the segment joins the first crossed edge to the last
    lengths = segment(np.argmax(crossed, axis=0), 3 - np.argmax(crossed[::-1], axis=0))
    saddle = crossed.all(axis=0)
    if np.any(saddle):
        # a and c on one side, b and d on the other: a centre on a's side joins a to c and cuts off
        # b (top, right) and d (bottom, left); else it cuts off a (top, left) and c (bottom, right)
        joins_a = (corners.sum(axis=0) > 0) == above[0]
        lengths = np.where(saddle, np.where(joins_a, segment(0, 1) + segment(2, 3), segment(0, 3) + segment(1, 2)),
                           lengths)
    return cells, lengths


def section_roughness(section: np.ndarray, sigma: float = SIGMA) -> float:
    """Roughness of one grain section (see the module docstring).

    Parameters
    ----------
    section : ndarray of bool, shape (H, W)
        The section's pixels (one connected piece or several; holes count), not empty.
    sigma : float
        Smoothing of the smooth outline, pixels (> 0).

    Returns
    -------
    float
        Outline length over the smoothed outline's length (about 1.05 for a digitised disc).
    """
    return float(_roughness([np.asarray(section, dtype=bool)], sigma)[0])


def _roughness(sections: list[np.ndarray], sigma: float) -> np.ndarray:
    """`section_roughness` of each of `sections` (bool, not empty), all in one pass (float64, (N,)).

    The sections are laid side by side in one strip, each in a tile padded beyond the
    Gaussian's reach, so one smoothing and one contour pass measure them all; each
    tile's smooth outline is at its own area-preserving level.
    """
    pad = int(4.0 * sigma + 0.5) + 1  # beyond scipy's Gaussian kernel (4 sigma): tiles do not mix
    widths = np.array([s.shape[1] + 2 * pad for s in sections])
    height = max(s.shape[0] for s in sections) + 2 * pad
    starts = np.concatenate([[0], np.cumsum(widths)])
    strip = np.zeros((height, int(starts[-1])), dtype=np.float32)
    for section, start in zip(sections, starts):
        strip[pad:pad + section.shape[0], start + pad:start + pad + section.shape[1]] = section
    tile = np.broadcast_to(np.repeat(np.arange(len(sections)), widths), strip.shape)
    smooth = ndimage.gaussian_filter(strip, sigma)
    # per tile, the level above which its smoothed section holds as many pixels as the section
    area = np.array([np.count_nonzero(s) for s in sections])
    key = np.sort((2.0 * tile - smooth).ravel())  # smooth is in [0, 1]: by tile, then by decreasing value
    ranked = 2.0 * np.repeat(np.arange(len(sections)), widths * height) - key
    first = starts[:-1] * height  # each tile's first position in `ranked` (tiles hold width x height pixels)
    level = 0.5 * (ranked[first + area - 1] + ranked[first + area])
    lengths = []
    for values in (strip.astype(np.float64) - 0.5, smooth.astype(np.float64) - level[tile]):
        (rows, columns), cell = _cell_lengths(values)
        lengths.append(np.bincount(tile[rows, columns], cell, minlength=len(sections)))
    return lengths[0] / lengths[1]


def slice_roughness(
    labels: np.ndarray, region: np.ndarray | None = None, *, min_area: int = MIN_AREA, sigma: float = SIGMA,
) -> np.ndarray:
    """Roughness of every grain section of one labelled slice.

    A section is measured when it has at least `min_area` pixels, does not touch the
    slice's border (a cut outline is partly straight) and its centroid lies in `region`.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        0 = pore, ``> 0`` = one grain each.
    region : ndarray of bool, shape (H, W), optional
        Where section centroids must lie; default: anywhere.
    min_area : int
        Pixels.
    sigma : float
        As in `section_roughness`, pixels.

    Returns
    -------
    ndarray of float64, shape (N,)
        One roughness per measured section, in label order.
    """
    labels = np.asarray(labels)
    sections = []
    for index, box in enumerate(ndimage.find_objects(labels)):
        if box is None or any(s.start == 0 or s.stop == n for s, n in zip(box, labels.shape)):
            continue
        section = labels[box] == index + 1
        if np.count_nonzero(section) < min_area:
            continue
        if region is not None:
            centroid = np.argwhere(section).mean(axis=0)
            if not region[tuple(int(round(c)) + s.start for c, s in zip(centroid, box))]:
                continue
        sections.append(section)
    return _roughness(sections, sigma) if sections else np.zeros(0)


def volume_roughness(
    labels: np.ndarray, region: np.ndarray | None = None, *, slices: int = SLICES, min_area: int = MIN_AREA,
    sigma: float = SIGMA,
) -> np.ndarray:
    """Roughness of the grain sections in evenly spaced slices (along axis 0) of a labelled volume.

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X)
        0 = pore, ``> 0`` = one grain each.
    region : ndarray of bool, shape (Z, Y, X), optional
        The part measured: slices are spread over the ones it reaches, and section
        centroids must lie in it (`slice_roughness`); default: the whole volume.
    slices : int
        At most this many slices, evenly spaced over the region's extent along z.
    min_area, sigma
        As in `slice_roughness` (pixels).

    Returns
    -------
    ndarray of float64, shape (N,)
        One roughness per measured section (possibly none).
    """
    labels = np.asarray(labels)
    reached = np.arange(labels.shape[0]) if region is None else np.flatnonzero(np.any(region, axis=(1, 2)))
    if not len(reached):
        return np.zeros(0)
    chosen = np.unique(reached[np.linspace(0, len(reached) - 1, min(slices, len(reached))).round().astype(int)])
    values = [slice_roughness(labels[z], None if region is None else region[z], min_area=min_area, sigma=sigma)
              for z in chosen]
    return np.concatenate(values)
