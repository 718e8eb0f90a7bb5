"""The realism report: every figure of a source scan and of synthetic packs, side by side.

`compare` measures the source scan (inside its specimen) and each synthetic pack
(its bulk region, `synthpack.realism.region`) with the structure
(`synthpack.realism.structure`), appearance (`synthpack.realism.appearance`) and
classifier (`synthpack.realism.discriminator`) measurements. Before any pack, it
runs the classifiers on the source against itself (`synthpack.realism.floor`): the
floor no pack can beat. Then it writes a report folder::

    realism.md        tables: source (and the floor), then one column per pack, and how to read them
    realism.json      the same figures (and the distributions' summaries)
    structure.png     grain size, shape, contacts and orientation distributions
    appearance.png    phase histograms, edge profiles, noise power spectra
    slices.png        one whole slice of each volume, all at the same pixels per voxel and in
                      the source's intensity window, the measured region outlined
    cnn_patches.png   per pack, the patches the CNN finds most synthetic next to random
                      real ones (when the CNN ran and there are packs)

The report's sections (``realism.md``; the same figures in ``realism.json``):

* **At a glance**, **Structure**, **Appearance**: the figures, source and packs;
* **Targets**: per pack, each figure against its target with pass / fail
  (`synthpack.realism.targets`: logistic and CNN AUC against the floor, W of each
  phase, noise std per phase, the NPS in every ring, solid fraction, mean
  coordination; every threshold a constant there), and, where the packs include a
  ``postprocess: none`` pack of the same pour, a line per other post-processing mode
  naming the target figures on which it is worse than ``none``;
* **Noise power spectrum**: the ratio pack / source in every ring (from the lowest,
  1/8 cycles per voxel, to the corner), per phase where measurable, and the worst ring;
* **Pore phase against distance from the grains**: the pore voxels' median and
  interquartile range in bands of one voxel from the nearest grain
  (`synthpack.measure.pore_bands`), a pack's band marked where it is off the source's;
* **Classifiers**: the floor and each pack's AUCs, margins and timings;
* **Where the classifiers see the difference**: each pack's AUCs with its grains, its pores,
  all but the boundaries or both phases made flat (`synthpack.realism.ablation`);
* the post-processing of each pack, and the pictures.

Distances (pack against source): KS = two-sample Kolmogorov-Smirnov distance (0 =
same distribution, 1 = disjoint); W = Wasserstein (earth mover's) distance of the
full-band intensity histograms (raw intensities of each phase, nothing filtered)
divided by the magnitude of the source's grain-pore contrast (0.05 = the histograms
are 5 % of the contrast apart on average), for grains brighter or darker than pores.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import stats

from .._shared.strict_json import dumps as strict_json
from ..io.atomic import Output, atomic_directory
from .._shared.windows import intensity_window
from ..store.pack import find_packs
from ..scan.core import Scan
from .ablation import ABLATIONS, ablated_patches
from .appearance import Appearance, measure_appearance, nps_ratio
from .discriminator import (DEFAULT_PATCH, MAX_PATCHES, ClassifierTest, CnnConfig, check_patch, classifier_test,
                            specimen_patches)
from .floor import DEFAULT_SLAB, check_slab, floor_test
from .region import Specimen
from ..measure.pore_width import pore_half_widths
from ..measure.specimen import solid_fraction
from .structure import GrainTable, fabric_eigenvalues, grain_table, ks_distance
from .targets import pack_targets, pour_key, worse_than_none

logger = logging.getLogger(__name__)

__all__ = ["Measurements", "RealismReport", "compare", "measure", "REPORT_OUTPUT"]

#: Pore voxels at most this half-width (voxels) are in narrow channels: gaps up to 4 voxels wide.
NARROW = 2

#: A report folder: an earlier report (``realism.json``) is replaced, anything else is refused.
REPORT_OUTPUT = Output("realism report", marker="realism.json")


@dataclass
class Measurements:
    """Everything measured on one specimen.

    Attributes
    ----------
    specimen : Specimen
    solid_fraction : float
        Of the bulk region, from the labels.
    grains : GrainTable
    appearance : Appearance
    patches : ndarray of float32, shape (N, S, S)
        Windowed patches for the classifier tests.
    patch_corners : ndarray of int64, shape (N, 3)
        Their ``(z, y0, x0)`` corners (the floor splits the source's by slice).
    pore_widths : ndarray of int64, shape (M,)
        The local half-width of every pore voxel of the region, voxels
        (`~synthpack.measure.pore_width.pore_half_widths`).
    """

    specimen: Specimen
    solid_fraction: float
    grains: GrainTable
    appearance: Appearance
    patches: np.ndarray
    patch_corners: np.ndarray
    pore_widths: np.ndarray

    def figures(self) -> dict:
        """Scalar figures of this specimen (JSON-able; None where not measurable)."""
        g, a = self.grains, self.appearance
        spectra = {phase: (s.centroid if s is not None else None) for phase, s in a.spectra.items()}
        return {
            "solid_fraction": self.solid_fraction,
            "pour_packing_fraction": self.specimen.packing_fraction,
            "region_voxels": int(np.count_nonzero(self.specimen.region)),
            "grains_measured": len(g),
            "diameter_median": _median(g.diameter),
            "sphericity_median": _median(g.sphericity),
            "elongation_median": _median(g.elongation),
            "flatness_median": _median(g.flatness),
            "coordination_mean": float(g.coordination.mean()) if len(g) else None,
            "axis_cosine_mean": float(g.axis_cosine.mean()) if len(g) else None,
            "fabric_eigenvalues": fabric_eigenvalues(g.long_axis).tolist() if len(g) else None,
            "roughness_median": _median(g.roughness),
            "roughness_p90": float(np.percentile(g.roughness, 90)) if len(g.roughness) else None,
            "pore_width_median": _median(self.pore_widths),
            "pore_narrow_share": float(np.mean(self.pore_widths <= NARROW)) if len(self.pore_widths) else None,
            "pore_level": a.profile.pore_level,
            "grain_level": a.profile.grain_level,
            "noise_grain": a.noise.grain_std,
            "noise_pore": a.noise.pore_std,
            "noise_grain_voxels": a.noise.n_grain,
            "noise_pore_voxels": a.noise.n_pore,
            "nps_centroid_grain": spectra["grains"],
            "nps_centroid_pore": spectra["pores"],
            "edge_width": a.edge_width,
            "edge_half_height": a.half_height,
            "pore_bands": a.pore_bands.to_dict(),
        }


def _median(values: np.ndarray) -> float | None:
    return float(np.median(values)) if len(values) else None


def measure(
    specimen: Specimen, window: tuple[float, float], *, patch: int = DEFAULT_PATCH, max_patches: int = MAX_PATCHES
) -> Measurements:
    """Measure a specimen's structure, appearance and classifier patches.

    Parameters
    ----------
    specimen : Specimen
    window : (float, float)
        Intensity window of the classifier patches (the source's).
    patch : int
        Classifier patch side, voxels.
    max_patches : int
        At most this many classifier patches, spread evenly over the region.
    """
    logger.info("measuring %s", specimen.name)
    patches, corners = specimen_patches(specimen, window, size=patch, max_patches=max_patches)
    return Measurements(specimen, solid_fraction(specimen.labels, specimen.region), grain_table(specimen),
                        measure_appearance(specimen), patches, corners,
                        pore_half_widths(specimen.labels, specimen.region))


def _ks(a: np.ndarray, b: np.ndarray) -> float | None:
    return ks_distance(a, b) if len(a) and len(b) else None


def distances(source: Measurements, pack: Measurements) -> dict:
    """Distances of `pack` from `source` (see the module docstring).

    Returns
    -------
    dict
        ``ks_<grain figure>``, ``wasserstein_<phase>``, ``edge_half_height_shift`` (pack
        minus source, voxels) and ``nps_ratio``: per phase (``grains``, ``pores``) the
        ring-by-ring power ratio pack / source of `~synthpack.realism.appearance.nps_ratio`,
        or None where a spectrum could not be measured.
    """
    sg, pg = source.grains, pack.grains
    sa, pa = source.appearance, pack.appearance
    contrast = abs(sa.contrast)
    result = {
        f"ks_{name}": _ks(getattr(sg, name), getattr(pg, name))
        for name in ("diameter", "sphericity", "elongation", "flatness", "coordination", "axis_cosine", "roughness")
    }
    result["ks_pore_width"] = _ks(source.pore_widths, pack.pore_widths)
    for phase, values in sa.samples.items():
        result[f"wasserstein_{phase}"] = float(stats.wasserstein_distance(values, pa.samples[phase]) / contrast)
    result["edge_half_height_shift"] = pa.half_height - sa.half_height
    result["nps_ratio"] = {
        phase: None if sa.spectra[phase] is None or pa.spectra[phase] is None
        else nps_ratio(pa.spectra[phase], sa.spectra[phase])
        for phase in sa.spectra
    }
    return result


@dataclass
class RealismReport:
    """The figures of a source and of packs, and the packs' distances from the source.

    Attributes
    ----------
    source : Measurements
    packs : list of Measurements
    distances : list of dict
        One per pack, from `distances`.
    floor : ClassifierTest or None
        The classifiers on the source against itself (`synthpack.realism.floor`).
    tests : list of ClassifierTest
        One per pack: the classifiers on the source against the pack.
    settings : dict
        How it was measured (window, patch size, slab, seed, CNN settings, pack paths,
        manifests' post-processing and `~synthpack.realism.targets.pour_key`).
    ablations : list of dict of str to ClassifierTest
        One per pack (empty without the ablation): per `~synthpack.realism.ablation.ABLATIONS`
        key, the classifiers on the source's and the pack's ablated patches.
    """

    source: Measurements
    packs: list[Measurements]
    distances: list[dict]
    floor: ClassifierTest | None = None
    tests: list[ClassifierTest] = field(default_factory=list)
    settings: dict = field(default_factory=dict)
    ablations: list[dict[str, ClassifierTest]] = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-able dict: settings, source figures, the floor, and per pack its figures and distances.

        A pack's ``distances["classifier"]`` holds ``n_per_class``, ``folds`` and per
        classifier (``logistic``, ``cnn``) its ``auc``, ``auc_std``, ``seconds`` and
        ``margin`` (AUC minus the floor's); ``floor`` holds the same for the source
        against itself, and ``slab``. A pack's ``distances["ablation"]`` holds, per
        ablation (`~synthpack.realism.ablation`), the same figures without margins (absent
        without the ablation). A pack's ``targets`` are its figures against the
        targets (`synthpack.realism.targets.pack_targets`); ``worse_than_none`` lists,
        per pack with a ``postprocess: none`` pack of the same pour among the packs,
        the target figures where it is worse than that pack
        (`synthpack.realism.targets.worse_than_none`).
        """
        floor = None if self.floor is None else {"slab": self.settings.get("slab"), **self.floor.summary()}
        source = {"name": self.source.specimen.name, "figures": self.source.figures()}
        packs = [{"name": m.specimen.name, "figures": m.figures(),
                  "distances": {**d, "classifier": t.summary(self.floor)}}
                 for m, d, t in zip(self.packs, self.distances, self.tests)]
        for pack, ablation in zip(packs, self.ablations):
            pack["distances"]["ablation"] = {name: test.summary() for name, test in ablation.items()}
        for pack in packs:
            pack["targets"] = pack_targets(source, pack, floor)
        return {
            "settings": self.settings,
            "source": source,
            "floor": floor,
            "packs": packs,
            "worse_than_none": worse_than_none(packs, self.settings.get("packs", [])),
        }

    def markdown(self) -> str:
        """The report as Markdown (tables and the pictures)."""
        from .markdown import report_markdown

        return report_markdown(self.to_dict())

    def write(self, out: str | os.PathLike, *, overwrite: bool = False) -> dict[str, Path]:
        """Write the report folder atomically (see the module docstring); returns the file paths.

        An earlier report in `out` is replaced; with `overwrite` a folder holding
        anything else receives the report's files and keeps its other files.

        Raises
        ------
        SynthpackInputError
            If `out` is a file, or a non-empty folder that is not an earlier report (and not `overwrite`).
        """
        from .plots import save_appearance_plot, save_cnn_patches_plot, save_slices_plot, save_structure_plot

        out = Path(out)
        names = ["realism.md", "realism.json", "structure.png", "appearance.png", "slices.png"]
        with atomic_directory(out, REPORT_OUTPUT, overwrite=overwrite) as staging:
            (staging / "realism.json").write_text(strict_json(self.to_dict(), indent=1))
            (staging / "realism.md").write_text(self.markdown())
            save_structure_plot(self.source, self.packs, staging / "structure.png")
            save_appearance_plot(self.source, self.packs, staging / "appearance.png")
            save_slices_plot(self.source, self.packs, tuple(self.settings["window"]), staging / "slices.png")
            if self.has_cnn_patches:
                save_cnn_patches_plot(self.packs, self.tests, staging / "cnn_patches.png", seed=self.settings["seed"])
                names.append("cnn_patches.png")
        return {name: out / name for name in names}

    @property
    def has_cnn_patches(self) -> bool:
        """Whether the report has a picture of the patches the CNN finds most synthetic."""
        return bool(self.tests) and all(t.cnn_scores is not None for t in self.tests)


def compare(
    source: Scan,
    packs: Sequence[str | os.PathLike] = (),
    *,
    patch: int = DEFAULT_PATCH,
    seed: int = 0,
    slab: int = DEFAULT_SLAB,
    cnn: CnnConfig | None = CnnConfig(),
    ablation: bool = True,
) -> RealismReport:
    """Measure a source scan and synthetic packs, and how far each pack is from the source.

    Parameters
    ----------
    source : Scan
        The real (source) scan, measured inside its specimen (`synthpack.measure.specimen.specimen_mask`).
    packs : sequence of path-like
        Pack folders, or folders holding pack folders; every pack gets its own column.
        Empty: the source and its floor only.
    patch : int
        Side (voxels) of the classifiers' in-slice patches.
    seed : int
        Seed of the classifiers' cross-validation folds and of the CNN.
    slab : int
        Slab thickness (slices along z) of the floor, the source against itself
        (`synthpack.realism.floor`).
    cnn : CnnConfig or None
        Settings of the CNN discriminator; None = the logistic regression only.
    ablation : bool
        Also run the classifiers on each pack's ablations (`synthpack.realism.ablation`:
        grains flat, pores flat, edges only, labels only), to show where the difference lies.

    Returns
    -------
    RealismReport
        Call ``.write(folder)`` to save it.

    Raises
    ------
    SynthpackInputError
        If a pack folder holds no pack, the source is too small for the floor's slabs, or
        the patch side is below 2 or wider than the source's or a pack's slices.
    """
    check_slab(slab)
    check_patch(patch, source.shape, "the source")
    directories = [p for path in packs for p in find_packs(path)]
    pack_manifests = {d: json.loads((Path(d) / "manifest.json").read_text()) for d in directories}
    for directory, manifest in pack_manifests.items():  # before any measuring
        check_patch(patch, tuple(manifest["shape"]), f"pack {directory}")
    window = intensity_window([source.tomogram])
    # twice the patches of a pack, so that each half of the floor has as many as a pack
    reference = measure(Specimen.from_scan(source), window, patch=patch, max_patches=2 * MAX_PATCHES)
    levels = {"grains": reference.appearance.profile.grain_level, "pores": reference.appearance.profile.pore_level}

    def ablated(measured: Measurements) -> dict[str, np.ndarray]:
        return ablated_patches(measured.patches, measured.specimen.labels, measured.patch_corners, levels, window)

    reference_ablated = ablated(reference) if ablation else {}
    logger.info("floor: the source's even against its odd slabs of %d slices", slab)
    floor = floor_test(reference.patches, reference.patch_corners, slab=slab, seed=seed, cnn=cnn)
    measured, manifests, tests, ablations = [], [], [], []
    for directory in directories:
        specimen = Specimen.from_pack(directory, name=_column_name(directory, directories))
        measured.append(measure(specimen, window, patch=patch))
        tests.append(classifier_test(reference.patches, measured[-1].patches, seed=seed, cnn=cnn,
                                     feature_groups=True))
        if ablation:
            logger.info("%s: the classifiers on its ablations", specimen.name)
            pack_ablated = ablated(measured[-1])
            ablations.append({name: classifier_test(reference_ablated[name], pack_ablated[name], seed=seed, cnn=cnn)
                              for name in ABLATIONS})
        manifest = pack_manifests[directory]
        manifests.append({"path": str(directory), "postprocess": manifest["config"]["postprocess"],
                          "mode": manifest.get("postprocess_mode"), "applied": manifest.get("postprocessing"),
                          "calibration": manifest.get("calibration"), "pour": pour_key(manifest)})
    settings = {"source": source.source, "window": list(window), "patch": patch, "seed": seed, "slab": slab,
                "cnn": None if cnn is None else dataclasses.asdict(cnn), "ablation": ablation, "packs": manifests}
    return RealismReport(reference, measured, [distances(reference, m) for m in measured], floor, tests, settings,
                         ablations)


def _column_name(directory: Path, directories: list[Path]) -> str:
    """The pack's folder name, or ``parent/name`` where two packs share a name."""
    directory = Path(directory)
    clash = sum(Path(d).name == directory.name for d in directories) > 1
    return f"{directory.parent.name}/{directory.name}" if clash else directory.name
