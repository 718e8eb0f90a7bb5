"""The realism report as Markdown, from the JSON-able dict of `RealismReport.to_dict`."""

from __future__ import annotations

__all__ = ["report_markdown"]

_HOW_TO_READ = """\
How to read it: the source is measured in the specimen (in each slice, the convex hull
of its labelled voxels: no container, no air, as in the source statistics the packs are
built from), each pack in its bulk region (one median grain diameter from the tube wall
and floor, two below the top). KS is the two-sample Kolmogorov-Smirnov distance between
the pack's and the
source's distributions (0 = the same, 1 = disjoint). W is the Wasserstein distance
between intensity histograms, as a fraction of the source's grain-pore contrast. Noise
is the standard deviation of the white noise with the same high-frequency content
(`synthpack.source.estimate_noise`); the NPS centroid is the power-weighted mean
frequency of the noise power spectrum in 8x8 in-slice patches (cycles/voxel: lower =
smoother noise and texture). The edge width is the 10-90 % rise distance of the mean
profile across grain-pore boundaries (voxels). The classifier AUC is the cross-validated
area under the ROC curve of a logistic regression on patch appearance features that tries
to tell synthetic from real patches: 0.5 = it cannot tell them apart, 1 = it always can.
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
    source, packs, settings = report["source"], report["packs"], report["settings"]
    names = [p["name"] for p in packs]
    header = ["", source["name"], *names]
    out = [f"# Realism report: {', '.join(names)} against {settings['source'] or source['name']}\n"]
    out.append(_HOW_TO_READ)
    out.append("## At a glance\n")
    glance = [
        ["classifier AUC (0.5 = indistinguishable)", "-",
         *[f"{p['distances']['classifier']['auc']:.3f} +- {p['distances']['classifier']['auc_std']:.3f}"
           for p in packs]],
        ["W grains / pores / edges", "-",
         *[" / ".join(f"{p['distances'][f'wasserstein_{k}']:.3f}" for k in ("grains", "pores", "edges"))
           for p in packs]],
        _row("noise in grains", "noise_grain", source, packs, digits=4),
        _row("noise in pores", "noise_pore", source, packs, digits=4),
        _row("edge width (voxels)", "edge_width", source, packs),
        _row("grain size: median diameter", "diameter_median", source, packs, ks="ks_diameter"),
    ]
    out.append(_table(header, glance))
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
        _row("NPS centroid in grains (cycles/voxel)", "nps_centroid_grain", source, packs),
        _row("NPS centroid in pores (cycles/voxel)", "nps_centroid_pore", source, packs),
        _row("edge width 10-90 (voxels)", "edge_width", source, packs),
        ["classifier AUC", "-", *[f"{p['distances']['classifier']['auc']:.3f}" for p in packs]],
        ["patches per class", "-", *[str(p["distances"]["classifier"]["n_per_class"]) for p in packs]],
    ]))
    out.append("\n## Post-processing of each pack\n")
    for pack, info in zip(packs, settings["packs"]):
        line = f"- **{pack['name']}** (`{info['path']}`): `postprocess: {info['postprocess']}`"
        calibration = info.get("calibration")
        if calibration:
            line += (f"; fitted blur sigma {calibration['blur_sigma']:.3f} voxels (edge width "
                     f"{calibration['edge_width']:.3f}, source {calibration['target_edge_width']:.3f}) and "
                     f"noise std {calibration['noise_std']:.4g} (source noise {calibration['target_noise']:.4g})")
        out.append(line + "\n")
    lo, hi = settings["window"]
    out.append(f"\nIntensity window of the patches and pictures: [{lo:.4g}, {hi:.4g}] (source 0.5-99.5 %); "
               f"patches {settings['patch']}x{settings['patch']} voxels.\n")
    out.append("\n## Pictures\n\n![slices](slices.png)\n\n![structure](structure.png)\n\n"
               "![appearance](appearance.png)\n")
    return "\n".join(out)
