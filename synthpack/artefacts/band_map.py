"""Map a pack's intensities onto its source's histograms, band by band of distance from the grain-pore boundary.

A scan's phases need not look the same at every distance from each other: a cement
paste is brighter and calmer next to its aggregates (an interfacial transition zone)
and holds unlabelled fine aggregate far from them, and a scanner's blur and scatter
carry a grain's level a few voxels into the pore. The render draws each phase alike
everywhere, and the fitted PSF and noise (`~synthpack.artefacts.calibrate`) cannot give
a phase a level or spread that depends on the distance. Where the calibration's guard
finds a phase histogram of the pack still beyond its target
(`~synthpack.artefacts.guard`), a `BandMap` is fitted: in each band of signed distance
(`~synthpack.measure.phase_histograms.band_of`: ``-k`` in the pore, ``+k`` in the grains,
``k = 1 .. BANDS``, the last open), the monotone map that takes the pack's quantiles of that
band (measured on the calibration's region, after the fitted steps) to the source's
(`~synthpack.source.SourceStatistics.band_histograms`). A voxel at distance ``d`` gets the
maps of the two bands whose knots (the mean ``|d|`` of the band's voxels; ``BANDS`` for
the open band) bracket ``|d|``, weighted linearly between them, so the map changes
smoothly with the distance (no contour at a band's edge); on each side of the boundary
its own bands. Beyond the ends of a band's quantiles the map shifts values by the end's
offset (no clipping: the darkest and brightest voxels keep their order and spread).

Being monotone in each band and continuous in the distance, the map keeps a voxel's rank
among its neighbours at the same distance: the pack's edges, noise and texture stay where
they are, and only the histogram of each shell changes. It has no random part.

`apply_band_map` applies it to a volume chunk by chunk: each chunk's labels are read with a
halo of `HALO` voxels, enough for every distance the map distinguishes, so the result is
the same whatever the chunks.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .._shared.chunks import bounded_map, chunk_boxes, thread_count
from ..errors import SynthpackInputError
from ..measure.edges import signed_distance
from ..measure.phase_histograms import BAND_KEYS, band_of, band_quantiles
from ..measure.pore_bands import BANDS
from .intensity import RoundLevels

logger = logging.getLogger(__name__)

__all__ = ["HALO", "BandMap", "apply_band_map", "fit_band_map"]

#: Voxels of labels read around a chunk: the open band's knot (`BANDS`) and one more.
HALO = BANDS + 1


def _strictly_increasing(quantiles: np.ndarray) -> np.ndarray:
    """`quantiles` made strictly increasing by the least nudge (ties of a quantised volume), for `np.interp`."""
    step = 1e-9 * (abs(float(quantiles[-1] - quantiles[0])) + 1.0)
    return np.maximum.accumulate(quantiles) + step * np.arange(len(quantiles))


def _quantile_map(values: np.ndarray, pack: np.ndarray, source: np.ndarray) -> np.ndarray:
    """`values` taken from the `pack` quantiles to the `source` ones; beyond the ends, shifted by the end's offset."""
    mapped = np.interp(values, pack, source)
    low, high = values < pack[0], values > pack[-1]
    mapped[low] = values[low] + (source[0] - pack[0])
    mapped[high] = values[high] + (source[-1] - pack[-1])
    return mapped


@dataclass(frozen=True)
class BandMap:
    """The pack-to-source quantile map of each band of signed distance (see the module docstring).

    Attributes
    ----------
    bands : tuple of int
        The bands mapped (of `~synthpack.measure.phase_histograms.BAND_KEYS`), increasing.
    knots : tuple of float
        Each band's knot: the mean ``|d|`` of its voxels in the fitted region (``BANDS`` for the
        open band), voxels.
    pack, source : tuple of tuple of float
        Each band's quantiles in the pack (strictly increasing) and in the source, intensity units.
    """

    bands: tuple[int, ...]
    knots: tuple[float, ...]
    pack: tuple[tuple[float, ...], ...]
    source: tuple[tuple[float, ...], ...]

    def apply(self, values: np.ndarray, distance: np.ndarray) -> np.ndarray:
        """The mapped intensities.

        Parameters
        ----------
        values : ndarray of float, any shape
            Intensities.
        distance : ndarray of float, same shape
            Signed distance of each voxel from the boundary (`~synthpack.measure.edges.signed_distance`),
            voxels; ``+-inf`` where a phase is farther than the map distinguishes.

        Returns
        -------
        ndarray of float32, same shape
            Voxels of a side with no band mapped keep their value.
        """
        values = np.asarray(values, dtype=np.float64)
        out = values.copy()
        for side in (-1, 1):
            index = sorted((i for i, band in enumerate(self.bands) if np.sign(band) == side),
                           key=lambda i: abs(self.bands[i]))  # nearest the boundary first
            if not index:
                continue
            selected = np.sign(distance) == side
            v, knots = values[selected], np.array([self.knots[i] for i in index])
            position = np.interp(np.abs(distance[selected]), knots, np.arange(len(index), dtype=np.float64))
            result = np.zeros_like(v)
            for j, i in enumerate(index):
                weight = np.clip(1.0 - np.abs(position - j), 0.0, None)
                near = weight > 0
                result[near] += weight[near] * _quantile_map(v[near], np.asarray(self.pack[i]),
                                                             np.asarray(self.source[i]))
            out[selected] = result
        return out.astype(np.float32)

    def side(self, sign: int) -> BandMap | None:
        """The map of the bands on one side of the boundary only (``-1``: the pores', ``+1``: the grains'), or None
        where it has none there; the other side's voxels then keep their values."""
        keep = [i for i, band in enumerate(self.bands) if np.sign(band) == sign]
        if not keep:
            return None
        return BandMap(tuple(self.bands[i] for i in keep), tuple(self.knots[i] for i in keep),
                       tuple(self.pack[i] for i in keep), tuple(self.source[i] for i in keep))

    def refitted(self, volume: np.ndarray, distance: np.ndarray, region: np.ndarray) -> BandMap | None:
        """The map of the same bands to the same source quantiles, from `volume`'s quantiles in `region` (a pack
        whose intensities a later step has changed, `~synthpack.artefacts.guard.guard_spectrum_match`), or None
        where a band of the map has no voxel there."""
        measured = band_quantiles(volume, distance, region)
        if any(measured[band] is None for band in self.bands):
            return None
        return BandMap(self.bands, self.knots, tuple(tuple(_strictly_increasing(measured[band]).tolist())
                                                     for band in self.bands), self.source)

    def to_dict(self) -> dict:
        """JSON-able dict of the fields (lists)."""
        return {"bands": list(self.bands), "knots": list(self.knots), "pack": [list(q) for q in self.pack],
                "source": [list(q) for q in self.source]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Sequence]) -> BandMap:
        """Read back what `to_dict` wrote."""
        return cls(tuple(int(b) for b in data["bands"]), tuple(float(k) for k in data["knots"]),
                   tuple(tuple(float(v) for v in q) for q in data["pack"]),
                   tuple(tuple(float(v) for v in q) for q in data["source"]))


def fit_band_map(volume: np.ndarray, distance: np.ndarray, region: np.ndarray,
                 source: Mapping[int, Sequence[float] | None]) -> BandMap | None:
    """The map that takes `volume`'s band histograms in `region` to `source`'s.

    Parameters
    ----------
    volume : ndarray of float32, shape (Z, Y, X)
        The pack after the calibration's fitted steps.
    distance : ndarray of float32, same shape
        Its signed distance from the boundary (`~synthpack.measure.edges.signed_distance`).
    region : ndarray of bool, same shape
        Where to measure.
    source : dict of int to sequence of float or None
        The source's quantiles per band (`~synthpack.source.SourceStatistics.band_histograms`).

    Returns
    -------
    BandMap or None
        Over the bands measured in both; None where there is none.
    """
    measured = band_quantiles(volume, distance, region)
    bands = tuple(band for band in BAND_KEYS if measured[band] is not None and source.get(band) is not None)
    if not bands:
        return None
    depth = np.abs(distance[region])
    of = band_of(distance[region])
    knots = tuple(float(BANDS) if abs(band) == BANDS else float(depth[of == band].mean()) for band in bands)
    return BandMap(bands, knots, tuple(tuple(_strictly_increasing(measured[band]).tolist()) for band in bands),
                   tuple(tuple(float(v) for v in source[band]) for band in bands))


def _distance(labels: np.ndarray) -> np.ndarray:
    """`~synthpack.measure.edges.signed_distance` of `labels`, or ``+-inf`` throughout where it holds one phase."""
    try:
        return signed_distance(labels)
    except SynthpackInputError:
        return np.full(labels.shape, np.inf if labels.any() else -np.inf, dtype=np.float32)


def apply_band_map(
    band_map: BandMap, volume, labels, chunks: tuple[int, int, int], *, threads: int | None = None,
    inside: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None, rounding: RoundLevels | None = None,
) -> None:
    """Apply `band_map` to `volume` in place, chunk by chunk.

    Parameters
    ----------
    band_map : BandMap
    volume : array of float32, shape (Z, Y, X)
        NumPy or Zarr; read and written one chunk at a time.
    labels : array of int, same shape
        Its labels (0 = pore); read with a `HALO`.
    chunks : tuple of 3 int
        Chunk shape.
    threads : int, optional
        Threads (default: the CPUs this process may use).
    inside : callable, optional
        ``inside(lo, hi) -> ndarray of bool`` of the chunk ``[lo, hi)``: the voxels to map (the
        specimen: not a container's wall or the air around it); default every voxel.
    rounding : RoundLevels, optional
        Round the mapped intensities to the source's grey-level grid, as the calibration's
        pipeline would have last; None: not rounded.
    """
    shape = tuple(volume.shape)

    def mapped(box: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        lo, hi = box
        grown_lo, grown_hi = np.maximum(lo - HALO, 0), np.minimum(hi + HALO, shape)
        distance = _distance(np.asarray(labels[tuple(slice(a, b) for a, b in zip(grown_lo, grown_hi))]))
        distance = distance[tuple(slice(a, b) for a, b in zip(lo - grown_lo, hi - grown_lo))]
        block = np.asarray(volume[tuple(slice(a, b) for a, b in zip(lo, hi))], dtype=np.float32)
        where = np.ones(block.shape, dtype=bool) if inside is None else inside(lo, hi)
        block[where] = band_map.apply(block[where], distance[where])
        return block if rounding is None else rounding(block, 0)

    for (lo, hi), block in bounded_map(mapped, chunk_boxes(shape, chunks), thread_count(threads)):
        volume[tuple(slice(a, b) for a, b in zip(lo, hi))] = block
