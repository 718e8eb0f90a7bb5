"""The realism report as Markdown, from the JSON-able dict of `RealismReport.to_dict`."""

from __future__ import annotations

from .targets import worse_line

__all__ = ["report_markdown"]

_HOW_TO_READ = """\
How to read it: the source is measured in the specimen (in each slice, the convex hull
of its labelled voxels: no container, no air, as in the source statistics the packs are
built from), each pack in its bulk region (one median grain diameter from the tube wall
and floor, two below the top; all of a pack that is an interior crop). KS is the two-sample Kolmogorov-Smirnov distance between
the pack's and the
source's distributions (0 = the same, 1 = disjoint). W is the Wasserstein distance
between intensity histograms, as a fraction of the source's grain-pore contrast. Noise
is the standard deviation of the white noise with the same high-frequency content
(`synthpack.measure.estimate_noise`, on the voxels two or more from every boundary: the
Appearance table gives how many; on a few hundred, as in small grains, it varies by about 10 %
from one realisation to the next); the NPS centroid is the power-weighted mean
frequency of the noise power spectrum in 8x8 in-slice patches of the noise alone (second
differences across slices; cycles/voxel: lower = smoother noise). The edge width is the 10-90 % rise distance of the mean
profile across grain-pore boundaries (voxels); its half height is the signed distance
from the label boundary (voxels, + into the grains) where that profile crosses half-way
from the pore to the grain level: 0 when the edge is centred on the boundary. The NPS
ratio is the pack's noise power over the source's in every frequency ring of the 8x8
spectrum, from the lowest (1/8 cycles/voxel) to the corner ring (1 = the same power; the
noise matches within a factor 2 in every ring when max |log2 ratio| <= 1). W is full band
(raw intensities, nothing filtered), so shading and blotches show in it that the noise
figure, a high-pass estimate, does not see. A classifier AUC is the cross-validated area under the ROC curve of a
model that tries to tell synthetic from real {patch}x{patch} in-slice patches: 0.5 = it cannot tell
them apart, 1 = it always can.

**The floor** (the source column of the AUC rows). Before any pack, each classifier is
asked to tell the source from itself: patches from its even slabs of {slab} slices along z
against those from its odd slabs. Whatever AUC it reaches there comes from the scan's own
variation (drift along z, grains that differ from place to place, the spread of the folds),
so no pack can be expected to do better: read a pack's AUC against the floor, not against
0.5. The margin is the pack's AUC minus the floor's; a margin within the folds' spread
(+-) means the classifier tells the pack from the source no better than the source from
itself.

**The two classifiers.** The logistic regression sees fixed summaries of each patch
(intensity histogram, histogram of neighbour differences, radial power spectrum). The CNN
is a small convolutional network (4 convolutions, about 16 k weights) trained from
scratch on the patches themselves, on the same folds, so it learns its own features: it
also catches what the summaries average away, such as the shape of an edge, a rim
around grains or the texture's grain. Each is a lower bound on how far the pack is from
the source: if either tells them apart, they differ. `cnn_patches.png` shows, per pack,
the patches the CNN scores as most synthetic (out of fold) next to random source
patches, in the same window: where to look first.
"""


def _fmt(value, digits: int = 3) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, int):
        return str(value)
    if abs(value) >= 100:
        return f"{value:.1f}"
    return f"{value:.{digits}g}" if abs(value) < 1e-2 and value != 0 else f"{value:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _row(label: str, key: str, source: dict, packs: list[dict], ks: str | None = None, digits: int = 3) -> list[str]:
    cells = [label, _fmt(source["figures"][key], digits)]
    for pack in packs:
        cell = _fmt(pack["figures"][key], digits)
        if ks is not None:
            cell += f" (KS {_fmt(pack['distances'][ks], 2)})"
        cells.append(cell)
    return cells


def _half_height_row(source: dict, packs: list[dict]) -> list[str]:
    """Half-height position of the edge profile, and each pack's shift from the source's."""
    return ["edge half height (voxels from the boundary, + = into grains)",
            f"{source['figures']['edge_half_height']:+.3f}",
            *[f"{p['figures']['edge_half_height']:+.3f} (shift {p['distances']['edge_half_height_shift']:+.3f})"
              for p in packs]]


def _auc(summary: dict | None, classifier: str, margin: bool = False) -> str:
    """``AUC +- sd`` of one classifier of a `ClassifierTest.summary`, with its margin over the floor."""
    if summary is None or classifier not in summary:
        return "n/a"
    result = summary[classifier]
    cell = f"{result['auc']:.3f} +- {result['auc_std']:.3f}"
    if margin and "margin" in result:
        cell += f" (margin {result['margin']:+.3f})"
    return cell


def _nps_cell(ratio: dict | None) -> str:
    """Range of the per-ring NPS ratios, the largest |log2 ratio| and its ring."""
    if ratio is None:
        return "n/a"
    return (f"{min(ratio['ratio']):.2f}-{max(ratio['ratio']):.2f} (max abs log2 {ratio['max_abs_log2']:.2f} "
            f"at {ratio['worst_frequency']:.3f})")


def _target_cell(row: dict) -> str:
    """A pack's figure against its target: the figure and pass / **FAIL** (n/a where not measured)."""
    if row["pass"] is None:
        return "n/a"
    return f"{row['cell']}: " + ("pass" if row["pass"] else "**FAIL**")


def _targets_section(report: dict) -> list[str]:
    """Per pack, each target figure with pass / fail, and the packs worse than their pour's ``none`` pack."""
    packs = report["packs"]
    if not packs:
        return []
    rows = [[first["figure"], first["target"], *[_target_cell(p["targets"][k]) for p in packs]]
            for k, first in enumerate(packs[0]["targets"])]
    rows.append(["targets met", "", *[f"{sum(r['pass'] is True for r in p['targets'])} of "
                                      f"{sum(r['pass'] is not None for r in p['targets'])} measured"
                                      for p in packs]])
    out = ["\n## Targets\n", "Each pack's figures against the targets (`synthpack.realism.targets`; AUC "
           "limits from the floor, relative figures against the source's).\n",
           _table(["figure", "target", *[p["name"] for p in packs]], rows)]
    out += [f"\n- {worse_line(flag)}\n" for flag in report.get("worse_than_none", [])]
    return out


def _classifier_section(report: dict) -> list[str]:
    """The floor against each pack, per classifier, and the CNN picture."""
    floor, packs = report["floor"], report["packs"]
    summaries = [p["distances"]["classifier"] for p in packs]
    header = ["", "floor (source vs itself)", *[p["name"] for p in packs]]
    rows = []
    for classifier, label in (("logistic", "logistic regression"), ("cnn", "CNN")):
        rows.append([f"{label} AUC", _auc(floor, classifier), *[_auc(s, classifier) for s in summaries]])
        rows.append([f"{label}: margin over the floor", "-",
                     *[f"{s[classifier]['margin']:+.3f}" if classifier in s else "n/a" for s in summaries]])
        rows.append([f"{label}: seconds", *[f"{s[classifier]['seconds']:.1f}" if s and classifier in s else "n/a"
                                            for s in (floor, *summaries)]])
    rows.append(["patches per class, folds", *[f"{s['n_per_class']}, {s['folds']}" if s else "n/a"
                                               for s in (floor, *summaries)]])
    out = ["\n## Classifiers\n", _table(header, rows)]
    settings = report["settings"]
    cnn = settings.get("cnn")
    out.append(f"\nFloor: even against odd slabs of {settings['slab']} slices along z. "
               + (f"CNN: {cnn['epochs']} epochs, batches of {cnn['batch_size']}, width {cnn['width']}, "
                  f"{cnn['threads']} thread(s).\n" if cnn else "CNN: not run.\n"))
    if packs and cnn:
        out.append("\n![patches the CNN finds most synthetic](cnn_patches.png)\n")
    return out


#: The report's words for each feature group of `synthpack.measure.patch_features.FEATURE_GROUPS`.
_FEATURE_GROUP_NAMES = {"intensities": "intensity histogram", "differences": "neighbour differences",
                        "spectrum": "power spectrum"}


def _ablation_section(packs: list[dict]) -> list[str]:
    """Per pack, its AUCs as it is and with phases made flat (`synthpack.realism.ablation`), and the logistic
    AUC of each feature group alone."""
    out = []
    if packs and "ablation" in packs[0]["distances"]:
        names = list(packs[0]["distances"]["ablation"])

        def cell(summary: dict) -> str:
            return " / ".join(f"{summary[c]['auc']:.3f}" if c in summary else "n/a" for c in ("logistic", "cnn"))

        rows = [["as it is", *[cell(p["distances"]["classifier"]) for p in packs]]]
        rows += [[name, *[cell(p["distances"]["ablation"][name]) for p in packs]] for name in names]
        out += [_table(["patches", *[p["name"] for p in packs]], rows),
                "Logistic / CNN AUC of the same patches, source and pack, with a phase made flat (set to the "
                "source's level of that phase), so that only the rest can tell the pack apart. Where making a phase "
                "flat brings an AUC down towards *labels only*, the difference lies in that phase (its texture, its "
                "level); where neither does but *edges only* keeps the AUC, the difference lies at the boundaries "
                "(the edge profile, the voxels next to the grains); *labels only* is the geometry alone: grain "
                "shapes, sizes and arrangement, nothing of the intensities. The phases are cut by a soft matte, the "
                "grain mask smoothed over about a voxel (`synthpack.realism.ablation`).\n"]
    if packs and all("logistic_features" in p["distances"]["classifier"] for p in packs):
        groups = list(packs[0]["distances"]["classifier"]["logistic_features"])
        out += [_table(["logistic AUC on one feature group alone", *[p["name"] for p in packs]],
                       [[_FEATURE_GROUP_NAMES.get(g, g),
                         *[f"{p['distances']['classifier']['logistic_features'][g]:.3f}" for p in packs]]
                        for g in groups]),
                "The logistic regression on the patches as they are, with one group of its features at a time "
                "(`synthpack.measure.patch_features.FEATURE_GROUPS`): a group whose AUC stays near the whole "
                "regression's is what tells the pack apart (grey levels, the steps between neighbouring pixels "
                "at edges and in the noise, or the texture's spectrum); a group near 0.5 already matches.\n"]
    return ["\n## Where the classifiers see the difference\n", *out] if out else []


def _nps_section(packs: list[dict]) -> list[str]:
    """Per ring, the NPS ratio pack / source in each phase measured in some pack, and the worst ring."""
    phases = [phase for phase in ("grains", "pores") if any(p["distances"]["nps_ratio"][phase] for p in packs)]
    columns = [(p["name"], phase, p["distances"]["nps_ratio"][phase]) for p in packs for phase in phases]
    measured = [ratio for _, _, ratio in columns if ratio is not None]
    if not measured:
        return []
    rows = [[f"{k + 1} ({frequency:.3f})",
             *["n/a" if ratio is None else f"{ratio['ratio'][k]:.2f}" for _, _, ratio in columns]]
            for k, frequency in enumerate(measured[0]["frequency"])]
    rows.append(["max abs log2 (ring)", *["n/a" if r is None else f"{r['max_abs_log2']:.2f} ({r['worst_frequency']:.3f})"
                                          for _, _, r in columns]])
    unmeasured = [phase for phase in ("grains", "pores") if phase not in phases]
    note = (f"\nNot measurable in {' or '.join(unmeasured)} (no 8x8 patch fits inside that phase's interior).\n"
            if unmeasured else "")
    return ["\n## Noise power spectrum: pack / source, ring by ring\n",
            "Every ring of the 8x8 spectrum but ring 0 (the patch mean): ring 1 is 1/8 cycles/voxel, rings "
            "above 4 (0.5 cycles/voxel) are the spectrum's corners (diagonal frequencies, where checkerboard "
            "texture shows).\n",
            _table(["ring (cycles/voxel)", *[f"{name}, {phase}" for name, phase, _ in columns]], rows), note]


#: A pack's pore band is marked where its median is this far from the source's (a fraction of the contrast) ...
BAND_LEVEL = 0.05
#: ... or its interquartile range more than this factor from the source's.
BAND_SPREAD = 1.5


def _band_cell(bands: dict, k: int, source: dict | None, contrast: float) -> str:
    """``median / IQR`` of band `k`, marked * where it differs from `source`'s bands (BAND_LEVEL, BAND_SPREAD)."""
    median, iqr = bands["median"][k], bands["iqr"][k]
    if median is None:
        return "n/a"
    cell = f"{_fmt(median)} / {_fmt(iqr)}"
    if source is None or source["median"][k] is None:
        return cell
    level = abs(median - source["median"][k]) > BAND_LEVEL * abs(contrast)
    spread = not 1 / BAND_SPREAD <= (iqr or 0.0) / max(source["iqr"][k], 1e-12) <= BAND_SPREAD
    return cell + (" *" if level or spread else "")


def _pore_bands_section(source: dict, packs: list[dict]) -> list[str]:
    """The pore phase's median / IQR in bands of distance from the nearest grain, source and packs."""
    reference = source["figures"]["pore_bands"]
    contrast = source["figures"]["grain_level"] - source["figures"]["pore_level"]
    n = len(reference["median"])
    rows = [[f"{k + 1}" if k < n - 1 else f"more than {n - 1}", _band_cell(reference, k, None, contrast),
             *[_band_cell(p["figures"]["pore_bands"], k, reference, contrast) for p in packs]] for k in range(n)]
    note = (f"Median / interquartile range of the pore voxels in each band of distance from the nearest grain "
            f"(band k: more than k - 1 and at most k voxels of signed distance from the boundary). * marks a "
            f"band whose median is more than {BAND_LEVEL:g} of the contrast from the source's, or whose spread "
            f"is more than {BAND_SPREAD:g}x off: a pore phase drawn the same everywhere where the source's "
            "changes near its grains.\n")
    return ["\n## Pore phase against distance from the grains\n",
            _table(["band (voxels)", "source", *[p["name"] for p in packs]], rows), note]


def _postprocessing_line(name: str, info: dict) -> str:
    """The report's line of one pack's post-processing: its mode and, if calibrated, what the fit applied and dropped."""
    line = f"- **{name}** (`{info['path']}`): `postprocess: {info['postprocess']}`"
    calibration = info.get("calibration")
    if calibration:
        line += (f"; fitted blur sigma {calibration['blur_sigma']:.3f} voxels (edge width "
                 f"{calibration['edge_width']:.3f}, source {calibration['target_edge_width']:.3f}) and "
                 f"noise std {calibration['noise_std']:.4g} (source noise {calibration['target_noise']:.4g})")
        guard = calibration.get("guard") or {}
        if guard.get("dropped"):
            line += f"; dropped by the guard: {', '.join(guard['dropped'])}"
        if calibration.get("band_map"):
            line += f"; band map of {len(calibration['band_map']['bands'])} shells of distance from the grains"
    return line + "\n"


def report_markdown(report: dict) -> str:
    """Markdown of a realism report.

    Parameters
    ----------
    report : dict
        `RealismReport.to_dict` output.

    Returns
    -------
    str
    """
    source, packs, settings, floor = report["source"], report["packs"], report["settings"], report["floor"]
    names = [p["name"] for p in packs]
    header = ["", source["name"], *names]
    against = settings["source"] or source["name"]
    out = [f"# Realism report: {', '.join(names)} against {against}\n" if names
           else f"# Realism report: the floor of {against}\n"]
    out.append(_HOW_TO_READ.format(slab=settings["slab"], patch=settings["patch"]))
    out.append("## At a glance\n")
    glance = [
        ["logistic AUC (0.5 = indistinguishable; source: its floor)", _auc(floor, "logistic"),
         *[_auc(p["distances"]["classifier"], "logistic", margin=True) for p in packs]],
        ["CNN AUC (source: its floor)", _auc(floor, "cnn"),
         *[_auc(p["distances"]["classifier"], "cnn", margin=True) for p in packs]],
        ["W grains / pores / edges", "-",
         *[" / ".join(f"{p['distances'][f'wasserstein_{k}']:.3f}" for k in ("grains", "pores", "edges"))
           for p in packs]],
        _row("noise in grains", "noise_grain", source, packs, digits=4),
        _row("noise in pores", "noise_pore", source, packs, digits=4),
        _row("edge width (voxels)", "edge_width", source, packs),
        _half_height_row(source, packs),
        ["NPS ratio pack / source in grains, every ring", "-",
         *[_nps_cell(p["distances"]["nps_ratio"]["grains"]) for p in packs]],
        ["NPS ratio pack / source in pores, every ring", "-",
         *[_nps_cell(p["distances"]["nps_ratio"]["pores"]) for p in packs]],
        _row("grain size: median diameter", "diameter_median", source, packs, ks="ks_diameter"),
    ]
    out.append(_table(header, glance))
    out += _targets_section(report)
    out.append("\n## Structure\n")
    out.append(_table(header, [
        _row("solid fraction (labels)", "solid_fraction", source, packs),
        _row("packing fraction (pour, meshes)", "pour_packing_fraction", source, packs),
        _row("voxels measured", "region_voxels", source, packs),
        _row("complete grains measured", "grains_measured", source, packs),
        _row("median equivalent diameter", "diameter_median", source, packs, ks="ks_diameter"),
        _row("median sphericity", "sphericity_median", source, packs, ks="ks_sphericity"),
        _row("median elongation b/a", "elongation_median", source, packs, ks="ks_elongation"),
        _row("median flatness c/b", "flatness_median", source, packs, ks="ks_flatness"),
        _row("mean coordination number", "coordination_mean", source, packs, ks="ks_coordination", digits=2),
        _row("mean abs cos(long axis, z) (0.5 isotropic)", "axis_cosine_mean", source, packs, ks="ks_axis_cosine"),
        _row("median section roughness (outline / smoothed outline)", "roughness_median", source, packs,
             ks="ks_roughness"),
        _row("90th percentile of the section roughness", "roughness_p90", source, packs),
        _row("median pore half-width (voxels; local thickness / 2)", "pore_width_median", source, packs,
             ks="ks_pore_width"),
        _row("share of the pore space in gaps at most 4 voxels wide", "pore_narrow_share", source, packs),
        ["fabric eigenvalues (1/3 each isotropic)",
         *[" / ".join(f"{v:.2f}" for v in (f["figures"]["fabric_eigenvalues"] or [])) or "n/a"
           for f in (source, *packs)]],
    ]))
    out.append("\n## Appearance\n")
    out.append(_table(header, [
        _row("pore level (interior median)", "pore_level", source, packs),
        _row("grain level (interior median)", "grain_level", source, packs),
        ["W grains / pores / edges (fraction of contrast)", "-",
         *[" / ".join(f"{p['distances'][f'wasserstein_{k}']:.3f}" for k in ("grains", "pores", "edges"))
           for p in packs]],
        _row("noise std in grains", "noise_grain", source, packs, digits=4),
        _row("noise std in pores", "noise_pore", source, packs, digits=4),
        ["voxels the noise is measured on, grains / pores",
         *[f"{f['figures'].get('noise_grain_voxels', 'n/a')} / {f['figures'].get('noise_pore_voxels', 'n/a')}"
           for f in (source, *packs)]],
        _row("NPS centroid in grains (cycles/voxel)", "nps_centroid_grain", source, packs),
        _row("NPS centroid in pores (cycles/voxel)", "nps_centroid_pore", source, packs),
        _row("edge width 10-90 (voxels)", "edge_width", source, packs),
        _half_height_row(source, packs),
    ]))
    out += _nps_section(packs)
    out += _pore_bands_section(source, packs)
    out += _classifier_section(report)
    out += _ablation_section(packs)
    if packs:
        out.append("\n## Post-processing of each pack\n")
    out += [_postprocessing_line(pack["name"], info) for pack, info in zip(packs, settings["packs"])]
    lo, hi = settings["window"]
    out.append(f"\nIntensity window of the patches and pictures: [{lo:.4g}, {hi:.4g}] (source 0.5-99.5 %); "
               f"patches {settings['patch']}x{settings['patch']} voxels.\n")
    out.append("\n## Pictures\n\n![slices](slices.png)\n\n![structure](structure.png)\n\n"
               "![appearance](appearance.png)\n")
    return "\n".join(out)
