"""Collision shapes against contacts (issue 15, "Real contacts"): what the pour's choices do to the pack.

Run from the repository root::

    .venv/bin/python bench/bench_contacts.py [--grains 300] [--variants hull decomposition hull-unshrunk]

Pours `--grains` grains of the ``large`` sample (batches of 50, seed 0, post-processing
``none``: the labels do not depend on it) once per variant, renders the labels and
measures them as the realism report does (``synthpack.realism``: complete grains
centred in the bulk region): the mean coordination number (grains sharing a voxel
face; the source's is printed too), the solid fraction of the bulk, and the pour's
seconds. Variants: ``hull`` (the default), ``decomposition`` (``pour.collision_shape:
decomposition``) and ``hull-unshrunk`` (the hull without the margin correction:
:func:`synthpack.physics.hulls.shrink_hull` replaced by the identity, so the
collision margin leaves a gap). Run it on an older tree (``PYTHONPATH``) for
"before" figures.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from synthpack.config import PackConfig
from synthpack.generate import generate_packs
from synthpack.library import ParticleLibrary
from synthpack.pack import open_pack
from synthpack.realism.region import Specimen
from synthpack.realism.report import solid_fraction
from synthpack.realism.structure import grain_table
from synthpack.samples import sample_scan


def measure(specimen: Specimen) -> tuple[float, float, int]:
    """(mean coordination number, solid fraction of the bulk, grains measured)."""
    grains = grain_table(specimen)
    return float(grains.coordination.mean()), solid_fraction(specimen.labels, specimen.region), len(grains)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grains", type=int, default=300)
    parser.add_argument("--variants", nargs="+", default=["hull", "hull-unshrunk", "decomposition"])
    args = parser.parse_args()
    scan = sample_scan("large", seed=0)
    coordination, solid, n = measure(Specimen.from_scan(scan))
    print(f"source `large`: coordination {coordination:.2f}, solid fraction {solid:.3f} ({n} grains)")
    library = ParticleLibrary.from_scan(scan, workers=1, progress=False)
    print("| variant | pour s | s / grain | coordination (source %.2f) | solid fraction of the bulk (source %.3f) "
          "| pour's packing fraction | grains measured |" % (coordination, solid))
    print("|---|---|---|---|---|---|---|")
    for variant in args.variants:
        if variant == "hull-unshrunk":
            from synthpack.physics import pybullet_engine
            pybullet_engine.shrink_hull = lambda hull, distance: np.asarray(hull.vertices)
        pour = {"n_particles": args.grains, "batch_size": 50}
        if variant == "decomposition":  # (without the key, the script also runs on older trees)
            pour["collision_shape"] = "decomposition"
        config = PackConfig.from_dict({"postprocess": "none", "pour": pour})
        with tempfile.TemporaryDirectory() as tmp:
            generate_packs(library, Path(tmp) / "packs", 1, config, workers=0, progress=False)
            pack = Path(tmp) / "packs" / "pack_0000"
            specimen = Specimen.from_pack(pack)
            coordination, solid, n = measure(specimen)
            checks = open_pack(pack).manifest["pour_checks"]
            pour_s, packing = checks["seconds"], checks["packing_fraction"]
        print(f"| {variant} | {pour_s:.1f} | {pour_s / args.grains:.4f} | {coordination:.2f} | {solid:.3f} "
              f"| {packing:.3f} | {n} |", flush=True)



if __name__ == "__main__":
    main()
