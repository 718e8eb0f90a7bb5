"""The realism targets: each pack's figures against them (pass / fail), and post-processing worse than none.

Every threshold is a module constant here, and nowhere else. A pack passes a target
when its *deviation* is at most the target's *limit*:

=======================  ===========================================  ==================================
figure                   deviation                                    limit
=======================  ===========================================  ==================================
logistic AUC             the AUC                                      the floor's + `LOGISTIC_AUC_MARGIN`
CNN AUC                  the AUC                                      the floor's + `CNN_AUC_MARGIN`
W grains, pores, edges   W (fraction of the source's contrast)        `W_LIMIT`
noise std, per phase     ``|pack / source - 1|``                      `NOISE_STD_TOLERANCE`
NPS, per phase           the largest ``|log2 ratio|`` over the rings  ``log2(NPS_RING_FACTOR)``
solid fraction           ``|pack - source|``                          `SOLID_FRACTION_TOLERANCE`
mean coordination        ``|pack / source - 1|``                      `COORDINATION_TOLERANCE`
=======================  ===========================================  ==================================

A figure that could not be measured (no CNN, a phase too thin for the NPS patches) is
neither passed nor failed (None); nor is a relative figure whose source value is 0.

**Worse than none.** A pack made with ``postprocess: none`` shows what the pour and the
render alone give. A pack of the same pour (`pour_key`: the same seed, library source
and config but for the post-processing and the run settings) with any other
post-processing must be at least as close to the source on every target figure: where
its deviation exceeds the ``none`` pack's by more than `WORSE_RESOLUTION` (for an AUC,
by more than the larger of the two AUCs' spreads over the folds, if that is larger: a
difference within it is the folds' chance; for a noise level, by more than the larger of the
two estimates' spreads between noise realisations on the voxels each rests on,
`~synthpack.measure.noise_estimate.estimate_spread`: 12 % on the 279 grain voxels of a small
block's grains), `worse_than_none` names the figure.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..measure.noise_estimate import estimate_spread
from ..measure.patch_features import LOGISTIC_AUC_MARGIN
from ..measure.spectrum import NPS_RING_FACTOR

__all__ = ["CNN_AUC_MARGIN", "COORDINATION_TOLERANCE", "LOGISTIC_AUC_MARGIN", "NOISE_STD_TOLERANCE",
           "NPS_RING_FACTOR", "SOLID_FRACTION_TOLERANCE", "TARGETS", "W_LIMIT", "WORSE_RESOLUTION", "Reading", "Target",
           "pour_key", "pack_targets", "worse_line", "worse_than_none"]

#: CNN AUC: at most this much above the floor.
CNN_AUC_MARGIN = 0.15
#: W of each phase (grains, pores, edges): at most this fraction of the source's grain-pore contrast.
W_LIMIT = 0.05
#: Noise standard deviation of each phase: within this fraction of the source's.
NOISE_STD_TOLERANCE = 0.10
#: Solid fraction of the bulk: within this (absolute) of the source's.
SOLID_FRACTION_TOLERANCE = 0.02
#: Mean coordination number: within this fraction of the source's.
COORDINATION_TOLERANCE = 0.20
#: A deviation counts as worse than the ``none`` pack's only when it exceeds it by more than this (an
#: AUC: by more than the larger spread over the folds of the two, if that is larger).
WORSE_RESOLUTION = 1e-3

#: The config sections that do not change the pour and render of a pack (see `pour_key`).
_NOT_THE_POUR = ("postprocess", "run")


@dataclass(frozen=True)
class Reading:
    """One figure of one pack read against its target.

    Attributes
    ----------
    deviation : float
        What is compared with `limit` (see the module docstring).
    limit : float
    cell : str
        The figure as the targets table shows it.
    gap : str
        The deviation as the worse-than-none line shows it.
    resolution : float
        Deviations closer than this are not told apart (`worse_than_none`).
    """

    deviation: float
    limit: float
    cell: str
    gap: str
    resolution: float = WORSE_RESOLUTION


@dataclass(frozen=True)
class Target:
    """One row of the targets table.

    Attributes
    ----------
    figure : str
        Its name, e.g. ``"W edges"``.
    target : str
        The target in words.
    read : callable
        ``read(source, pack) -> Reading or None``; `source` is ``RealismReport.to_dict()["source"]``
        (its ``figures``), `pack` one entry of
        ``RealismReport.to_dict()["packs"]`` (its ``figures`` and ``distances``, the
        latter with ``classifier``), extended by ``floor`` (the floor's summary or None).
        None where the figure was not measured.
    """

    figure: str
    target: str
    read: Callable[[dict, dict], Reading | None]


def _auc(classifier: str, margin: float) -> Callable[[dict, dict], Reading | None]:
    def read(source: dict, pack: dict) -> Reading | None:
        floor, summary = pack["floor"], pack["distances"]["classifier"]
        if floor is None or classifier not in floor or classifier not in summary:
            return None
        auc, limit = summary[classifier]["auc"], floor[classifier]["auc"] + margin
        return Reading(auc, limit, f"{auc:.3f} (limit {limit:.3f})", f"{auc:.3f}",
                       max(WORSE_RESOLUTION, summary[classifier]["auc_std"]))
    return read


def _wasserstein(phase: str) -> Callable[[dict, dict], Reading | None]:
    def read(source: dict, pack: dict) -> Reading | None:
        value = pack["distances"].get(f"wasserstein_{phase}")
        return None if value is None else Reading(value, W_LIMIT, f"{value:.3f}", f"{value:.3f}")
    return read


def _figure(value: float, digits: int | None) -> str:
    """`value` with `digits` decimals, or (None) three significant digits and no exponent.

    Intensities come in any unit (0-1 floats, 8- or 16-bit grey values), so a noise level is
    shown to its significant digits: 0.0116, 45.3, 1234, never 0.0.
    """
    if digits is not None:
        return f"{value:.{digits}f}"
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    return f"{value:.{max(0, 2 - math.floor(math.log10(abs(value))))}f}"


def _relative(key: str, tolerance: float, digits: int | None, voxels: str | None = None,
              ) -> Callable[[dict, dict], Reading | None]:
    """Pack's figure `key` within `tolerance` (a fraction) of the source's (`digits`: see `_figure`). A noise level
    with its count of voxels (the figure `voxels`) shows the spread of the ratio between noise realisations (of
    the pack's estimate and the source's, `~synthpack.measure.noise_estimate.estimate_spread`), and is told
    apart from another pack's only beyond its own estimate's spread (the reading's resolution)."""
    def read(source: dict, pack: dict) -> Reading | None:
        reference, value = source["figures"].get(key), pack["figures"].get(key)
        if reference is None or value is None or not (math.isfinite(reference) and math.isfinite(value)) \
                or reference == 0:
            return None
        change = value / reference - 1
        count = pack["figures"].get(voxels) if voxels else None
        resolution, spread = WORSE_RESOLUTION, ""
        if count:
            ratio = value / abs(reference)
            resolution = max(WORSE_RESOLUTION, estimate_spread(count) * ratio)
            counts = [count] + ([source["figures"][voxels]] if source["figures"].get(voxels) else [])
            spread = f" ± {math.hypot(*(estimate_spread(n) for n in counts)) * ratio:.1%}"  # both estimates vary
        return Reading(abs(change), tolerance, f"{_figure(value, digits)} (source {_figure(reference, digits)}, "
                       f"{change:+.1%}{spread})", f"{abs(change):.1%} off", resolution)
    return read


def _absolute(key: str, tolerance: float) -> Callable[[dict, dict], Reading | None]:
    """Pack's figure `key` within `tolerance` of the source's."""
    def read(source: dict, pack: dict) -> Reading | None:
        reference, value = source["figures"].get(key), pack["figures"].get(key)
        if reference is None or value is None:
            return None
        deviation = abs(value - reference)
        return Reading(deviation, tolerance, f"{value:.3f} (source {reference:.3f}, {value - reference:+.3f})",
                       f"{deviation:.3f} off")
    return read


def _nps(phase: str) -> Callable[[dict, dict], Reading | None]:
    def read(source: dict, pack: dict) -> Reading | None:
        ratio = pack["distances"]["nps_ratio"].get(phase)
        if ratio is None:
            return None
        factor = 2.0 ** ratio["max_abs_log2"]
        return Reading(ratio["max_abs_log2"], math.log2(NPS_RING_FACTOR),
                       f"worst ring {ratio['worst_frequency']:.3f}: x{ratio['worst_ratio']:.2f}",
                       f"worst ring off x{factor:.2f}")
    return read


#: The targets table, in its order (one entry per row).
TARGETS: tuple[Target, ...] = (
    Target("logistic AUC", f"<= floor + {LOGISTIC_AUC_MARGIN}", _auc("logistic", LOGISTIC_AUC_MARGIN)),
    Target("CNN AUC", f"<= floor + {CNN_AUC_MARGIN}", _auc("cnn", CNN_AUC_MARGIN)),
    *(Target(f"W {phase}", f"<= {W_LIMIT} of the contrast", _wasserstein(phase))
      for phase in ("grains", "pores", "edges")),
    Target("noise std in grains", f"within {NOISE_STD_TOLERANCE:.0%}",
           _relative("noise_grain", NOISE_STD_TOLERANCE, None, "noise_grain_voxels")),
    Target("noise std in pores", f"within {NOISE_STD_TOLERANCE:.0%}",
           _relative("noise_pore", NOISE_STD_TOLERANCE, None, "noise_pore_voxels")),
    *(Target(f"NPS in {phase}, every ring", f"within {NPS_RING_FACTOR:g}x", _nps(phase))
      for phase in ("grains", "pores")),
    Target("solid fraction", f"within {SOLID_FRACTION_TOLERANCE}", _absolute("solid_fraction",
                                                                            SOLID_FRACTION_TOLERANCE)),
    Target("mean coordination", f"within {COORDINATION_TOLERANCE:.0%}",
           _relative("coordination_mean", COORDINATION_TOLERANCE, 2)),
)


def pack_targets(source: dict, pack: dict, floor: dict | None) -> list[dict]:
    """Every target of `TARGETS`, read on one pack.

    Parameters
    ----------
    source : dict
        ``RealismReport.to_dict()["source"]`` (its ``figures``).
    pack : dict
        One entry of ``RealismReport.to_dict()["packs"]`` (its ``figures`` and ``distances``).
    floor : dict or None
        The floor's classifier summary (``RealismReport.to_dict()["floor"]``).

    Returns
    -------
    list of dict
        One per target, in order: ``figure``, ``target`` (in words), ``deviation``,
        ``limit``, ``pass`` (bool; all three None where not measured), ``cell`` and
        ``gap`` (texts) and ``resolution`` (`Reading`), None where not measured.
    """
    rows = []
    for target in TARGETS:
        reading = target.read(source, {**pack, "floor": floor})
        row = {"figure": target.figure, "target": target.target}
        if reading is None:
            row.update(deviation=None, limit=None, cell=None, gap=None, resolution=None)
            row["pass"] = None
        else:
            row.update(deviation=reading.deviation, limit=reading.limit, cell=reading.cell, gap=reading.gap,
                       resolution=reading.resolution)
            row["pass"] = bool(reading.deviation <= reading.limit)
        rows.append(row)
    return rows


def pour_key(manifest: dict) -> str:
    """A short digest of what makes a pack's pour and render: its seed, library source and config but
    its post-processing and run settings (`synthpack.store.pack`'s ``manifest.json``).

    Two packs with the same key differ only in their post-processing.
    """
    config = {key: value for key, value in manifest["config"].items() if key not in _NOT_THE_POUR}
    identity = {"seed": manifest.get("seed"), "library_source": manifest.get("library_source"), "config": config}
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()[:16]


def worse_than_none(packs: Sequence[dict], infos: Sequence[dict]) -> list[dict]:
    """For every pack with post-processing that has a ``none`` pack of the same pour, where it is worse.

    Parameters
    ----------
    packs : sequence of dict
        ``RealismReport.to_dict()["packs"]`` entries, each with its ``targets`` (`pack_targets`).
    infos : sequence of dict
        The same packs' ``settings["packs"]`` entries: ``mode`` (the post-processing
        applied) and ``pour`` (`pour_key`).

    Returns
    -------
    list of dict
        One per such pack: ``pack`` and ``mode`` (its name and post-processing),
        ``none`` (the ``none`` pack's name) and ``worse``: a list of ``figure``,
        ``gap`` and ``none_gap`` (the deviations as text) for every target where the
        pack's deviation exceeds the ``none`` pack's by more than the larger of their
        resolutions (empty: nowhere worse).
    """
    nones = {}
    for pack, info in zip(packs, infos):
        if info.get("mode") == "none":
            nones.setdefault(info.get("pour"), pack)
    result = []
    for pack, info in zip(packs, infos):
        none = nones.get(info.get("pour"))
        if info.get("mode") == "none" or none is None:
            continue
        worse = [{"figure": mine["figure"], "gap": mine["gap"], "none_gap": theirs["gap"]}
                 for mine, theirs in zip(pack["targets"], none["targets"])
                 if mine["deviation"] is not None and theirs["deviation"] is not None
                 and mine["deviation"] > theirs["deviation"] + max(mine["resolution"], theirs["resolution"])]
        result.append({"pack": pack["name"], "mode": info.get("mode"), "none": none["name"], "worse": worse})
    return result


def worse_line(flag: dict) -> str:
    """One entry of `worse_than_none` in words, e.g. ``"calibrated (pack_a) is worse than none (pack_b, the
    same pour) on: W edges (0.062 > 0.054)"``, or that it is nowhere worse."""
    who, none = f"{flag['mode']} ({flag['pack']})", f"none ({flag['none']}, the same pour)"
    if not flag["worse"]:
        return f"{who} is nowhere worse than {none}"
    return f"{who} is worse than {none} on: " + ", ".join(
        f"{w['figure']} ({w['gap']} > {w['none_gap']})" for w in flag["worse"])
