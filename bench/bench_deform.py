"""How free-form deformation moves a pack's grain shapes: sphericity and elongation against the source.

Run from the repository root::

    .venv/bin/python bench/bench_deform.py                 # 150 grains, seeds 0 and 1, about 6 minutes on 2 cores
    .venv/bin/python bench/bench_deform.py --grains 60 --seeds 0

It builds the particle library of the built-in "large" sample scan once, then for each
``grains.deform.strength`` (0, 0.1, 0.2, 0.3) generates packs (same seeds, no
post-processing: only the labels are measured), measures every complete grain centred
in each pack's bulk with the realism report's grain table
(`synthpack.realism.structure.grain_table`, on the rendered labels) and prints a
Markdown table: medians, and the Kolmogorov-Smirnov distance to the source scan's grain
table, of sphericity and elongation, and their interquartile ranges (the spread of the
shapes; the grains of all seeds pooled), with the share of deformations damped to avoid a
fold and the seconds spent deforming per grain.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import generate_pack
from synthpack.library.core import ParticleLibrary
from synthpack.realism.region import Specimen
from synthpack.realism.structure import grain_table, ks_distance
from synthpack.scan.samples import sample_scan

STRENGTHS = (0.0, 0.1, 0.2, 0.3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grains", type=int, default=150, help="grains per pack (default 150)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="run seeds (default 0 1)")
    args = parser.parse_args()

    scan = sample_scan("large", seed=0)
    library = ParticleLibrary.from_scan(scan, workers=1, progress=False)
    source = grain_table(Specimen.from_scan(scan))
    rows = [("source", len(source), source.sphericity, source.elongation, "", "")]
    base = PackConfig().replace(pour={"n_particles": args.grains, "batch_size": 50}, postprocess="none")
    with tempfile.TemporaryDirectory() as tmp:
        for strength in STRENGTHS:
            config = base.replace(grains={"deform": {"strength": strength}})
            tables, damped, seconds = [], [], 0.0
            for seed in args.seeds:
                out = Path(tmp) / f"s{strength}-{seed}"
                path = generate_pack(library, 0, config.replace(seed=seed), out, threads=2)
                tables.append(grain_table(Specimen.from_pack(path, clean=True)))
                manifest = json.loads((path / "manifest.json").read_text())
                seconds += manifest["timings"].get("deform", 0.0)
                grains = json.loads((path / "placements.json").read_text()).get("grains")
                damped += [f < 1 for f in grains["factors"]] if grains else [False] * args.grains
            sphericity = np.concatenate([t.sphericity for t in tables])
            elongation = np.concatenate([t.elongation for t in tables])
            per_grain = seconds / (args.grains * len(args.seeds))
            rows.append((f"{strength:g}", len(sphericity), sphericity, elongation, f"{np.mean(damped):.0%}",
                         f"{per_grain:.3f}"))
    print("| strength | grains measured | sphericity median (IQR) | KS sphericity | elongation median (IQR) | "
          "KS elongation | damped | s/grain deforming |")
    print("|---|---|---|---|---|---|---|---|")
    for name, n, sphericity, elongation, damped, seconds in rows:
        ks_s = "" if name == "source" else f"{ks_distance(sphericity, source.sphericity):.3f}"
        ks_e = "" if name == "source" else f"{ks_distance(elongation, source.elongation):.3f}"
        print(f"| {name} | {n} | {_spread(sphericity)} | {ks_s} | {_spread(elongation)} | {ks_e} | "
              f"{damped} | {seconds} |")


def _spread(values: np.ndarray) -> str:
    """``median (interquartile range)``."""
    q1, median, q3 = np.percentile(values, [25, 50, 75])
    return f"{median:.3f} ({q3 - q1:.3f})"


if __name__ == "__main__":
    main()
