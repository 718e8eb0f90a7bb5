"""Pictures of the realism report (PNG): structure, appearance, slices side by side at one scale, the CNN's picks."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_file
from .._shared.plotting import pyplot
from .._shared.seeds import generator
from .discriminator import ClassifierTest
from .report import Measurements

__all__ = ["save_appearance_plot", "save_cnn_patches_plot", "save_slices_plot", "save_structure_plot", "slice_layout"]

_DPI = 72
#: The slices picture: at most this many pixels per voxel, panels within about this width (pixels),
#: gaps between them and room for the titles above (pixels).
_MAX_SCALE = 4
_SLICES_WIDTH = 1800
_GAP = 12
_TITLE = 34
#: Patches shown per set in the CNN picture (a square number).
_SHOWN = 16


def _save(fig, path: str | os.PathLike) -> Path:
    with atomic_file(path) as staging:
        fig.savefig(staging, dpi=_DPI, format="png")
    pyplot().close(fig)
    return Path(path)


def _cdf(ax, values: np.ndarray, label: str) -> None:
    if len(values):
        ax.plot(np.sort(values), np.linspace(0, 1, len(values)), label=label)


def save_structure_plot(source: Measurements, packs: Sequence[Measurements], path: str | os.PathLike) -> Path:
    """Cumulative distributions of grain size, shape, contacts, long-axis orientation and section roughness.

    Parameters
    ----------
    source : Measurements
    packs : sequence of Measurements
    path : path-like
        Output PNG.
    """
    plt = pyplot()
    fig, axes = plt.subplots(2, 4, figsize=(17, 7), layout="constrained")
    unit = source.specimen.unit
    panels = [
        ("diameter", f"equivalent diameter [{unit}]"), ("sphericity", "sphericity"),
        ("elongation", "elongation b/a"), ("flatness", "flatness c/b"),
        ("coordination", "coordination number"), ("axis_cosine", "|cos(long axis, z)|"),
        ("roughness", "section roughness (outline / smoothed outline)"),
    ]
    for ax, (name, label) in zip(axes.ravel(), panels):
        for measured in (source, *packs):
            values = np.asarray(getattr(measured.grains, name), dtype=float)
            _cdf(ax, values, f"{measured.specimen.name} ({len(values)})")
        ax.set_xlabel(label)
        ax.set_ylabel("fraction of grain sections" if name == "roughness" else "fraction of grains")
    axes[1, 1].plot([0, 1], [0, 1], "k:", lw=1, label="isotropic")
    axes[1, 3].set_axis_off()
    axes[0, 0].legend(fontsize=8)
    return _save(fig, path)


def save_appearance_plot(source: Measurements, packs: Sequence[Measurements], path: str | os.PathLike) -> Path:
    """Phase histograms, normalised edge profiles and noise power spectra.

    Parameters
    ----------
    source : Measurements
    packs : sequence of Measurements
    path : path-like
        Output PNG.
    """
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), layout="constrained")
    everyone = (source, *packs)
    for ax, phase in zip(axes[0], ("grains", "pores", "edges")):
        pooled = np.concatenate([m.appearance.samples[phase] for m in everyone])
        bins = np.linspace(*np.percentile(pooled, [0.5, 99.5]), 60)
        for measured in everyone:
            ax.hist(measured.appearance.samples[phase], bins=bins, density=True, histtype="step",
                    label=measured.specimen.name)
        ax.set_xlabel(f"intensity of {phase}")
        ax.set_ylabel("density")
    axes[0, 0].legend(fontsize=8)
    ax = axes[1, 0]
    for measured in everyone:
        profile = measured.appearance.profile
        ax.plot(profile.distance, profile.normalised, marker=".",
                label=f"{measured.specimen.name} (10-90 {measured.appearance.edge_width:.2f}, "
                      f"half height {measured.appearance.half_height:+.2f})")
    ax.set_xlabel("signed distance from the grain boundary [voxels]")
    ax.set_ylabel("normalised mean intensity")
    ax.legend(fontsize=8)
    for ax, phase in zip(axes[1, 1:], ("grains", "pores")):
        for measured in everyone:
            spectrum = measured.appearance.spectra[phase]
            if spectrum is not None:
                ax.semilogy(spectrum.frequency[1:], spectrum.power[1:], marker=".", label=measured.specimen.name)
        ax.set_xlabel(f"frequency [cycles/voxel], {phase}")
        ax.set_ylabel("noise power per ring")
    return _save(fig, path)


def slice_layout(
    shapes: Sequence[tuple[int, int]], *, width: int = _SLICES_WIDTH, max_scale: int = _MAX_SCALE
) -> tuple[float, tuple[int, int], list[tuple[float, float, float, float]]]:
    """Boxes of slices side by side, all at one scale (pixels per voxel), for `save_slices_plot`.

    Parameters
    ----------
    shapes : sequence of (int, int)
        Each slice's ``(rows, columns)``, voxels.
    width : int
        The panels and the gaps between them fit into about this many pixels (unless
        a scale of 1 pixel per voxel would still be wider: then the scale is below 1).
    max_scale : int
        At most this many pixels per voxel.

    Returns
    -------
    scale : float
        Pixels per voxel, the same for every panel; a whole number when at least 1.
    size : (int, int)
        Figure width and height, pixels.
    boxes : list of (float, float, float, float)
        Per slice, ``(left, bottom, width, height)`` in pixels from the figure's lower left
        corner: ``width = scale * columns``, ``height = scale * rows``, tops aligned
        below the titles.
    """
    columns = sum(shape[1] for shape in shapes)
    scale = min(float(max_scale), (width - _GAP * (len(shapes) + 1)) / columns)
    scale = float(np.floor(scale)) if scale >= 1 else scale
    height = scale * max(shape[0] for shape in shapes)
    size = (int(np.ceil(scale * columns + _GAP * (len(shapes) + 1))), int(np.ceil(height + _TITLE + _GAP)))
    boxes, left = [], float(_GAP)
    for rows, cols in shapes:
        boxes.append((left, size[1] - _TITLE - scale * rows, scale * cols, scale * rows))
        left += scale * cols + _GAP
    return scale, size, boxes


def save_slices_plot(
    source: Measurements, packs: Sequence[Measurements], window: tuple[float, float], path: str | os.PathLike
) -> Path:
    """One whole z slice of each volume side by side, at one scale and in one intensity window.

    Each volume's slice is the middle of its bulk region's z range, shown whole (a
    container, air, empty corners show as they are), its bulk region outlined. Every
    panel has the same pixels per voxel (`slice_layout`), so a pack smaller or larger
    than the source looks so, and the same window (the source's), so a pack brighter,
    darker or of lower contrast does too.

    Parameters
    ----------
    source : Measurements
    packs : sequence of Measurements
    window : (float, float)
        Intensities shown black and white (the source's window).
    path : path-like
        Output PNG.
    """
    plt = pyplot()
    everyone = (source, *packs)
    slices = []
    for measured in everyone:
        z = np.flatnonzero(measured.specimen.region.any(axis=(1, 2)))
        z = int((z[0] + z[-1]) // 2) if len(z) else measured.specimen.region.shape[0] // 2
        slices.append((z, measured.specimen.tomogram[z], measured.specimen.region[z]))
    scale, size, boxes = slice_layout([image.shape for _, image, _ in slices])
    fig = plt.figure(figsize=(size[0] / _DPI, size[1] / _DPI))
    for measured, (z, image, region), (left, bottom, width, height) in zip(everyone, slices, boxes):
        ax = fig.add_axes((left / size[0], bottom / size[1], width / size[0], height / size[1]))
        ax.imshow(image, cmap="gray", vmin=window[0], vmax=window[1], origin="lower",
                  interpolation="nearest" if scale >= 1 else "antialiased")
        if region.any() and not region.all():
            ax.contour(region.astype(np.float32), levels=[0.5], colors="tab:orange", linewidths=1)
        ax.set_title(f"{measured.specimen.name}, z = {z}\n{image.shape[0]} x {image.shape[1]} voxels", fontsize=9)
        ax.set_axis_off()
    return _save(fig, path)


def _mosaic(patches: np.ndarray) -> np.ndarray:
    """Square grid of equal patches (K, S, S), K a square number, one NaN pixel between them."""
    side, size = int(round(np.sqrt(len(patches)))), patches.shape[1]
    grid = np.full((side * (size + 1) - 1, side * (size + 1) - 1), np.nan, dtype=np.float32)
    for k, patch in enumerate(patches):
        row, column = divmod(k, side)
        grid[row * (size + 1):row * (size + 1) + size, column * (size + 1):column * (size + 1) + size] = patch
    return grid


def save_cnn_patches_plot(
    packs: Sequence[Measurements], tests: Sequence[ClassifierTest], path: str | os.PathLike, *, seed: int = 0
) -> Path:
    """Per pack, the patches the CNN finds most synthetic next to random real ones.

    The synthetic patches are the 16 with the highest out-of-fold CNN score (each
    scored by the network that did not see it in training); the real ones are 16
    drawn at random (seeded) from the same test. All are shown in the same window,
    the report's patch window (0 = black, 1 = white).

    Parameters
    ----------
    packs : sequence of Measurements
    tests : sequence of ClassifierTest
        One per pack, with ``cnn_scores`` (real = set 0, synthetic = set 1).
    path : path-like
        Output PNG.
    seed : int
        Seed of the draw of the real patches.
    """
    plt = pyplot()
    rng = generator(seed, "plots")
    fig, axes = plt.subplots(len(packs), 2, figsize=(8, 4.2 * len(packs)), layout="constrained", squeeze=False)
    cmap = plt.get_cmap("gray").with_extremes(bad="tab:blue")
    for (left, right), measured, test in zip(axes, packs, tests):
        real, synthetic = np.flatnonzero(test.target == 0), np.flatnonzero(test.target == 1)
        shown = min(_SHOWN, len(real), len(synthetic))
        shown = int(np.sqrt(shown)) ** 2
        picked = rng.choice(real, shown, replace=False)
        worst = synthetic[np.argsort(test.cnn_scores[synthetic], kind="stable")[::-1][:shown]]
        left.imshow(_mosaic(test.patches[picked]), cmap=cmap, vmin=0.0, vmax=1.0, interpolation="nearest")
        left.set_title(f"source: {shown} random patches", fontsize=10)
        right.imshow(_mosaic(test.patches[worst]), cmap=cmap, vmin=0.0, vmax=1.0, interpolation="nearest")
        right.set_title(f"{measured.specimen.name}: the {shown} the CNN finds most synthetic", fontsize=10)
        for ax in (left, right):
            ax.set_axis_off()
    return _save(fig, path)
