"""Preview pictures (PNG) for checking results by eye."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .io.atomic import Output, atomic_file
from ._shared.plotting import pyplot
from .library.core import ParticleLibrary
from .library.particles import equivalent_diameter
from .scan.core import Scan

__all__ = ["label_overlay", "save_label_preview", "save_library_preview"]


#: The PNG text entry that marks a picture as synthpack's own (replaced on a rerun).
_SOFTWARE = "synthpack"


def _is_our_png(path: Path) -> bool:
    from PIL import Image

    try:
        with Image.open(path) as image:
            return image.format == "PNG" and image.text.get("Software") == _SOFTWARE
    except OSError:
        return False


#: A preview picture: an earlier synthpack preview is replaced, any other file is refused.
PREVIEW_OUTPUT = Output("preview picture", folder=False, is_ours=_is_our_png)


def _save_png(fig, path: str | os.PathLike, dpi: int, overwrite: bool) -> Path:
    with atomic_file(path, PREVIEW_OUTPUT, overwrite=overwrite) as staging:
        fig.savefig(staging, dpi=dpi, format="png", metadata={"Software": _SOFTWARE})
    return Path(path)


def label_overlay(image: np.ndarray, labels: np.ndarray, alpha: float = 0.45) -> np.ndarray:
    """Blend a grey slice with one random colour per label.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Intensities (any range; scaled by its 1st-99th percentiles).
    labels : ndarray of int, shape (H, W)
        Instance labels, 0 = background (left grey).
    alpha : float
        Opacity of the label colours.

    Returns
    -------
    ndarray of float, shape (H, W, 3)
        RGB in [0, 1].
    """
    lo, hi = np.percentile(image, [1, 99])
    grey = np.clip((image - lo) / max(hi - lo, 1e-12), 0, 1)
    rgb = np.repeat(grey[..., None], 3, axis=-1)
    palette = np.random.default_rng(0).uniform(0.2, 1.0, size=(int(labels.max()) + 1, 3))
    colours = palette[labels]
    inside = labels > 0
    rgb[inside] = (1 - alpha) * rgb[inside] + alpha * colours[inside]
    return rgb


def _draw_mesh(ax, mesh, colour) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    shading = 0.45 + 0.55 * np.clip(mesh.face_normals @ np.array([0.3, -0.4, 0.87]), 0, 1)
    faces = Poly3DCollection(mesh.vertices[mesh.faces], linewidths=0.1, edgecolors="k")
    faces.set_facecolor(np.clip(np.outer(shading, colour), 0, 1))
    ax.add_collection3d(faces)
    half = np.abs(mesh.vertices).max()
    for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setter(-half, half)
    ax.set_axis_off()


def save_library_preview(
    scan: Scan, library: ParticleLibrary, path: str | os.PathLike, n_meshes: int = 6, *, overwrite: bool = False
) -> Path:
    """Write a PNG: the scan's middle slices with labels, the size distribution, and meshes.

    Parameters
    ----------
    scan : Scan
        The source scan.
    library : ParticleLibrary
        Its particle library.
    path : path-like
        Output PNG.
    n_meshes : int
        How many particle meshes to draw (spread over the size range; rounded
        to a multiple of 3, at least 3).
    overwrite : bool
        Replace an existing file at `path` that is not a synthpack preview.
    """
    plt = pyplot()

    n_meshes = max(3, 3 * (n_meshes // 3))
    fig = plt.figure(figsize=(13, 7.5), layout="constrained")
    grid = fig.add_gridspec(2, n_meshes, height_ratios=(1.4, 1))
    span = n_meshes // 3
    views = _middle_slices(scan.shape)[:2]
    for column, (axis, index) in enumerate(views):
        ax = fig.add_subplot(grid[0, column * span : (column + 1) * span])
        ax.imshow(label_overlay(scan.tomogram[index], scan.labels[index]), origin="lower")
        ax.set_title(f"source: middle {axis} slice + labels")
        ax.set_axis_off()
    ax = fig.add_subplot(grid[0, 2 * span :])
    ax.hist(library.equivalent_diameters, bins=20, color="0.4")
    ax.set_xlabel(f"equivalent diameter [{library.unit}]")
    ax.set_ylabel("particles")
    ax.set_title(f"{len(library)} particles in the library")
    order = np.argsort(library.equivalent_diameters)
    picks = order[np.linspace(0, len(order) - 1, min(n_meshes, len(order))).astype(int)]
    for column, index in enumerate(picks):
        ax = fig.add_subplot(grid[1, column], projection="3d")
        particle = library[int(index)]
        _draw_mesh(ax, particle.mesh, np.array([0.85, 0.7, 0.45]))
        ax.set_title(f"label {particle.label}\n{len(particle.mesh.faces)} faces", fontsize=9)
    try:
        return _save_png(fig, path, 90, overwrite)
    finally:
        plt.close(fig)


def complete_grain_diameters(labels: np.ndarray, voxel_size: tuple[float, float, float]) -> np.ndarray:
    """Equivalent-sphere diameter of every label present that no face of the volume cuts, physical units, shape (N,).

    A grain cut by a face (an interior crop's, or a tube's top) shows only part of its volume,
    as the source's border grains do, which the library leaves out too.
    """
    labels = np.asarray(labels)
    counts = np.bincount(labels.ravel())
    cut = np.unique(np.concatenate([np.take(labels, index, axis=axis).ravel()
                                    for axis in range(3) for index in (0, -1)]))
    counts[cut] = 0
    counts[0] = 0
    return equivalent_diameter(counts[counts > 0] * float(np.prod(voxel_size)))


def save_pack_preview(
    tomogram: np.ndarray,
    clean: np.ndarray,
    labels: np.ndarray,
    voxel_size: tuple[float, float, float],
    unit: str,
    source_diameters: np.ndarray,
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
) -> Path:
    """Write a PNG to check a synthetic pack by eye.

    Top row: the middle z, y and x slices of the post-processed tomogram with the
    labels overlaid. Bottom row: one slice before and after post-processing, and
    the grain-size distribution of the source particles against the synthetic
    pack's grains that are whole in view (`complete_grain_diameters`).

    Parameters
    ----------
    tomogram, clean : ndarray, shape (Z, Y, X)
        Post-processed and clean tomograms.
    labels : ndarray of int, shape (Z, Y, X)
        Instance labels.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)``.
    unit : str
        Length unit.
    source_diameters : ndarray, shape (M,)
        Equivalent diameters of the source particles (e.g. the library's).
    path : path-like
        Output PNG.
    overwrite : bool
        Replace an existing file at `path` that is not a synthpack preview.
    """
    plt = pyplot()

    fig, axes = plt.subplots(2, 3, figsize=(14, 9.5), layout="constrained")
    views = _middle_slices(labels.shape)
    for ax, (axis, index) in zip(axes[0], views):
        ax.imshow(label_overlay(np.asarray(tomogram[index]), np.asarray(labels[index])), origin="lower")
        ax.set_title(f"synthetic: middle {axis} slice + labels")
        ax.set_axis_off()
    lo, hi = np.percentile(clean, [0.5, 99.5])
    for ax, volume, title in ((axes[1, 0], clean, "before post-processing"),
                              (axes[1, 1], tomogram, "after post-processing")):
        ax.imshow(volume[views[0][1]], cmap="gray", vmin=lo, vmax=hi, origin="lower")
        ax.set_title(f"middle z slice, {title}")
        ax.set_axis_off()
    ax = axes[1, 2]
    synthetic = complete_grain_diameters(labels, voxel_size)
    bins = np.linspace(0, max(source_diameters.max(), synthetic.max(initial=0.0)) * 1.05, 25)
    ax.hist(source_diameters, bins=bins, density=True, alpha=0.6, label=f"source particles ({len(source_diameters)})")
    if len(synthetic):
        ax.hist(synthetic, bins=bins, density=True, alpha=0.6, label=f"synthetic grains, whole in view ({len(synthetic)})")
    ax.set_xlabel(f"equivalent diameter [{unit}]")
    ax.set_ylabel("density")
    ax.legend()
    ax.set_title("grain-size distribution")
    try:
        return _save_png(fig, path, 80, overwrite)
    finally:
        plt.close(fig)


def _middle_slices(shape: tuple[int, ...]) -> list[tuple[str, tuple]]:
    """The middle z, y and x slices of a volume of `shape`: ``(axis name, index)`` each."""
    middle = np.asarray(shape) // 2
    return [("z", np.s_[middle[0], :, :]), ("y", np.s_[:, middle[1], :]), ("x", np.s_[:, :, middle[2]])]


def save_label_preview(
    tomogram: np.ndarray, labels: np.ndarray, path: str | os.PathLike, *, overwrite: bool = False
) -> Path:
    """Write a PNG to check starting labels (`synthpack.scan.labelling`) by eye.

    The middle z, y and x slices of the tomogram, grey, with the outline of every
    label drawn in colour (`skimage.segmentation.mark_boundaries`), above the same
    slices with the labels filled in.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities.
    labels : ndarray of int, shape (Z, Y, X)
        Instance labels, 0 = background.
    path : path-like
        Output PNG.
    overwrite : bool
        Replace an existing file at `path` that is not a synthpack preview.
    """
    plt = pyplot()
    from skimage.segmentation import mark_boundaries

    fig, axes = plt.subplots(2, 3, figsize=(14, 9.5), layout="constrained")
    views = _middle_slices(labels.shape)
    lo, hi = np.percentile(tomogram, [1, 99])
    for column, (axis, index) in enumerate(views):
        grey = np.clip((np.asarray(tomogram[index], dtype=np.float64) - lo) / max(hi - lo, 1e-12), 0, 1)
        axes[0, column].imshow(mark_boundaries(grey, np.asarray(labels[index]), color=(1, 0.3, 0.1)), origin="lower")
        axes[0, column].set_title(f"middle {axis} slice + label outlines")
        axes[1, column].imshow(label_overlay(np.asarray(tomogram[index]), np.asarray(labels[index])), origin="lower")
        axes[1, column].set_title(f"middle {axis} slice + labels")
    for ax in axes.ravel():
        ax.set_axis_off()
    fig.suptitle(f"{int(labels.max())} grains: a starting point to check and correct, not ground truth")
    try:
        return _save_png(fig, path, 80, overwrite)
    finally:
        plt.close(fig)
