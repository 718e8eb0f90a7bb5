"""The pack's structure against the pour's choices (issue 15): collision shapes and packing targets.

Run from the repository root::

    .venv/bin/python bench/bench_structure.py --sample large --variants hull hull-unshrunk decomposition
    .venv/bin/python bench/bench_structure.py --sample small --variants none 0.50 0.55 0.60 source
    .venv/bin/python bench/bench_structure.py --sample concrete --variants none source   # ../shared

Pours `--grains` grains of the sample's library (batches of 50, seed 0, post-processing
``none``: the labels do not depend on it) once per variant, renders the labels and
measures them as the realism report does (``synthpack.realism``: complete grains
centred in the bulk region): the mean coordination number (grains sharing a voxel
face), the solid fraction of the bulk, and the pour's seconds, next to the source's.
``--sample concrete`` is the real neutron CT of ``../shared/data/concrete`` (skipped
with a message when absent).

Variants:

* ``hull`` (the default shapes), ``decomposition`` (``pour.collision_shape:
  decomposition``) and ``hull-unshrunk`` (the hull without the margin correction:
  :func:`synthpack.physics.hulls.shrink_hull` replaced by the identity, so the
  collision margin leaves a gap), each with a free pour (``target_solid_fraction:
  none``), to see the shapes alone;
* ``none``, a number, or ``source``: the value of ``pour.target_solid_fraction``
  with the default shapes.

Run it on an older tree (``PYTHONPATH``) for "before" figures (the shape variants
only: older trees have no packing target).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import generate_packs
from synthpack.io import read_scan
from synthpack.library.core import ParticleLibrary
from synthpack.store.pack import open_pack
from synthpack.realism.region import Specimen
from synthpack.realism.report import solid_fraction
from synthpack.realism.structure import grain_table
from synthpack.scan.samples import sample_scan

CONCRETE = Path(__file__).resolve().parents[2] / "shared" / "data" / "concrete"
SHAPES = ("hull", "hull-unshrunk", "decomposition")


def measure(specimen: Specimen) -> tuple[float, float, int]:
    """(mean coordination number, solid fraction of the bulk, grains measured)."""
    grains = grain_table(specimen)
    return float(grains.coordination.mean()), solid_fraction(specimen.labels, specimen.region), len(grains)


def pour_settings(variant: str, grains: int) -> dict:
    """The ``pour`` section of a variant (see the module docstring)."""
    pour: dict = {"n_particles": grains, "batch_size": 50}
    if variant in SHAPES:
        pour["target_solid_fraction"] = "none"
        if variant == "decomposition":
            pour["collision_shape"] = "decomposition"
    else:
        pour["target_solid_fraction"] = variant if variant in ("none", "source") else float(variant)
    return pour


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", default="large", choices=["large", "small", "concrete"])
    parser.add_argument("--grains", type=int, default=300)
    parser.add_argument("--variants", nargs="+", default=["hull", "hull-unshrunk", "decomposition"])
    args = parser.parse_args()
    if args.sample == "concrete":
        if not CONCRETE.is_dir():
            sys.exit(f"{CONCRETE} is absent: the concrete scan is not part of this repository")
        scan = read_scan(CONCRETE / "concrete_neutron.tif", CONCRETE / "concrete_neutron_labels_watershed.tif",
                         voxel_size=1.0, unit="px")
    else:
        scan = sample_scan(args.sample, seed=0)
    coordination, solid, n = measure(Specimen.from_scan(scan))
    print(f"source `{args.sample}`: coordination {coordination:.2f}, solid fraction {solid:.3f} ({n} grains)")
    library = ParticleLibrary.from_scan(scan, workers=1, progress=False)
    print(f"| variant | pour s | s / grain | coordination (source {coordination:.2f}) "
          f"| solid fraction of the bulk (source {solid:.3f}) | pour's packing fraction | target reached "
          "| grains measured |")
    print("|---|---|---|---|---|---|---|---|")
    for variant in args.variants:
        if variant == "hull-unshrunk":
            from synthpack.physics import pybullet_engine
            pybullet_engine.shrink_hull = lambda hull, distance: np.asarray(hull.vertices)
        config = PackConfig.from_dict({"postprocess": "none", "pour": pour_settings(variant, args.grains)})
        with tempfile.TemporaryDirectory() as tmp:
            generate_packs(library, Path(tmp) / "packs", 1, config, workers=0, progress=False)
            pack = Path(tmp) / "packs" / "pack_0000"
            coordination, solid, n = measure(Specimen.from_pack(pack))
            manifest = open_pack(pack).manifest
        checks, pour_s = manifest["pour_checks"], manifest["timings"]["pour_engine"]
        print(f"| {variant} | {pour_s:.1f} | {pour_s / args.grains:.4f} | {coordination:.2f} | {solid:.3f} "
              f"| {checks['packing_fraction']:.3f} | {checks.get('target_reached', '-')} | {n} |", flush=True)


if __name__ == "__main__":
    main()
