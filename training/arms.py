"""The experiment's training arms, and the training sets of those that take part of an export.

Per real scan ``s`` the arm kinds (`ARM_KINDS`) are:

================  ===================  ============================================================
kind              arm name             trains on
================  ===================  ============================================================
``real``          ``s``                the real training slices (the paper's "real only")
``syn``           ``s+syn``            the real training slices + the calibrated packs
``syn-nopp``      ``s+syn-nopp``       the real training slices + the packs' clean tomograms
``syn-only``      ``s:syn``            the calibrated packs only: no real slice
``syn-rand``      ``s:syn-rand``       packs with ``postprocess: randomised`` only
``budget``        ``s@K``, ``s@K+syn`` K real training slices (`budget_slices`), without / with
                                       the calibrated packs
``syn-first``     ``s+syn-first``,     the training set of ``s+syn`` (and of each ``s@K+syn`` where
                  ``s@K+syn-first``    the config has ``budget`` arms too), the packs' slices first:
                                       pretraining on packs, then fine-tuning on the real slices
================  ===================  ============================================================

A ``syn-first`` arm sees the same images, as many times each, as its ``+syn`` twin, in the
same number of steps: only the order differs (every epoch of the packs' slices, then every
epoch of the real ones: `training.unet.item_order`), so the pair measures pretraining on packs
against mixing them in at equal compute. The U-Net families draw their own batches and take
it; YOLO, whose batches ultralytics draws, does not.

Every arm validates on the scan's real val slices (model selection) and is tested on
the real test block; no arm ever trains on a val or test slice. Each arm is trained by one
model family (`MODEL_FAMILIES`): YOLO arms are named as above, U-Net arms take the prefix
``unet_`` (``unet_large+syn``) and the same dataset (`Arm.dataset`). Arms that take part
of an export's training images (``syn-only``, ``syn-rand``, ``budget``) get a
dataset folder of their own (`subset_dataset`) whose ``data.yaml`` lists those
images in a ``train.txt`` and points at the export's own val and test images.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from synthpack.errors import SynthpackInputError
from synthpack.io import atomic_file
from synthpack.scan.split import slice_splits

__all__ = ["ARM_KINDS", "DEFAULT_KINDS", "FIRST_SUFFIX", "MODEL_FAMILIES", "Arm", "budget_slices", "dataset_images",
           "make_arms", "subset_dataset", "synthetic_images"]

#: Arm kinds and what they train on.
ARM_KINDS = {
    "real": "real only",
    "syn": "real + synthetic",
    "syn-nopp": "real + synthetic w/o post-processing",
    "syn-only": "synthetic only",
    "syn-rand": "synthetic only, randomised post-processing",
    "budget": "K real slices, without / with synthetic",
    "syn-first": "synthetic first, then real",
}
#: The kinds of a config without ``arms:`` (``syn-first`` only where asked for: YOLO has no form of it).
DEFAULT_KINDS = tuple(kind for kind in ARM_KINDS if kind != "syn-first")
#: The name suffix of a ``syn-first`` arm: its twin's name (``s+syn``, ``s@K+syn``) and this.
FIRST_SUFFIX = "-first"
#: Model families, the prefix of their arms' names and what they are, in the report's words.
MODEL_FAMILIES = {
    "yolo": ("", "YOLOv8-seg (Ultralytics), instances from its masks"),
    "unet": ("unet_", "2D U-Net (MONAI) on the border-core target, instances by watershed from interior seeds"),
    "unet3d": ("unet3d_", "3D U-Net (MONAI) on PatchDataset patches of the border-core target, instances by 3D "
                          "watershed from interior seeds"),
}
#: Export of each pack variant, by its suffix: calibrated packs, their clean tomograms, randomised packs.
EXPORT_SUFFIXES = {"real": "", "syn": "+syn", "syn-nopp": "+syn-nopp", "syn-rand": "+syn-rand"}


@dataclass(frozen=True)
class Arm:
    """One training set.

    Attributes
    ----------
    name : str
        E.g. ``large``, ``large+syn``, ``large:syn``, ``large@10+syn``; ``unet_large`` for
        the U-Net family.
    scan : str
        The real scan it belongs to (its val slices select the model).
    kind : str
        A key of `ARM_KINDS`.
    export : str
        The export whose images it uses: a key of `EXPORT_SUFFIXES`.
    real_slices : int or None
        Real training slices it keeps: None for all of them, else that many (`budget_slices`).
    synthetic : bool
        Whether it keeps the export's synthetic training slices.
    family : str
        Its model family, a key of `MODEL_FAMILIES`.
    packs_first : bool
        Whether it trains on its packs' slices first, then on the real ones (``syn-first``).
    """

    name: str
    scan: str
    kind: str
    export: str
    real_slices: int | None = None
    synthetic: bool = True
    family: str = "yolo"
    packs_first: bool = False

    @property
    def dataset(self) -> str:
        """Its dataset's name (``data/<dataset>``): `name` without the family's prefix (nor `FIRST_SUFFIX`: a
        ``syn-first`` arm trains on its twin's dataset)."""
        return self.name[len(MODEL_FAMILIES[self.family][0]):].removesuffix(FIRST_SUFFIX)

    @property
    def whole_export(self) -> bool:
        """Whether it trains on its export as it is (no `subset_dataset`)."""
        return self.real_slices is None

    @property
    def description(self) -> str:
        """What it trains on, in words."""
        if self.real_slices:
            what = f"{self.real_slices} real slices" + (" + synthetic" if self.synthetic else "")
            return what + (", synthetic first" if self.packs_first else "")
        return ARM_KINDS[self.kind]


def make_arms(kinds: dict[str, list[str]], budgets: list[int], family: str = "yolo") -> list[Arm]:
    """The arms of `kinds` (kind -> real scan names), with `budgets` for ``budget``, scan by scan, of `family`."""
    scans = list(dict.fromkeys(scan for names in kinds.values() for scan in names))
    prefix = MODEL_FAMILIES[family][0]
    arms = []

    def add(name: str, *fields, **options) -> None:
        arms.append(Arm(prefix + name, *fields, **options, family=family))

    for scan in scans:
        wanted = {kind for kind, names in kinds.items() if scan in names}
        if "real" in wanted:
            add(scan, scan, "real", "real")
        if "syn" in wanted:
            add(scan + "+syn", scan, "syn", "syn")
        if "syn-nopp" in wanted:
            add(scan + "+syn-nopp", scan, "syn-nopp", "syn-nopp")
        if "syn-only" in wanted:
            add(scan + ":syn", scan, "syn-only", "syn", real_slices=0)
        if "syn-rand" in wanted:
            add(scan + ":syn-rand", scan, "syn-rand", "syn-rand", real_slices=0)
        if "budget" in wanted:
            for k in budgets:
                add(f"{scan}@{k}", scan, "budget", "real", real_slices=k, synthetic=False)
                add(f"{scan}@{k}+syn", scan, "budget", "syn", real_slices=k)
        if "syn-first" in wanted:
            add(scan + "+syn" + FIRST_SUFFIX, scan, "syn-first", "syn", packs_first=True)
            for k in budgets if "budget" in wanted else []:
                add(f"{scan}@{k}+syn{FIRST_SUFFIX}", scan, "syn-first", "syn", real_slices=k, packs_first=True)
    return arms


def budget_slices(n_slices: int, k: int, val_fraction: float) -> np.ndarray:
    """`k` real training slices chosen evenly over the training part of a volume of `n_slices` slices.

    The training part is `synthpack.scan.split.slice_splits`' ``train``: the test block and the
    val slices next to it are never chosen. The first and last training slices are always
    taken (for ``k >= 2``) and the rest spaced evenly by rank between them.

    Parameters
    ----------
    n_slices : int
    k : int
        At least 0, at most the number of training slices.
    val_fraction : float
        That of the export (`slice_splits`).

    Returns
    -------
    ndarray of int64
        Sorted, distinct slice indices.
    """
    train = slice_splits(n_slices, val_fraction)["train"]
    if not 0 <= k <= len(train):
        raise SynthpackInputError(f"a label budget of {k} slices needs 0 to {len(train)} (the scan's training "
                                  "slices): lower the budgets of the experiment config")
    if k == 0:
        return train[:0]
    ranks = np.unique(np.round(np.linspace(0, len(train) - 1, k)).astype(np.int64))
    return train[ranks]


def subset_dataset(export: Path, out: Path, arm: Arm) -> dict[str, int]:
    """Write ``out/data.yaml`` and ``out/train.txt``: `arm`'s part of the training images of `export`.

    The val and test images are the export's. ``out/dataset.json`` (written last: it marks
    the folder as done) records the image counts and the real slices chosen. An existing
    complete folder is kept.

    Returns
    -------
    dict
        Images per split, ``{"train": ..., "val": ..., "test": ...}``.
    """
    done = out / "dataset.json"
    if done.is_file():
        return json.loads(done.read_text())["images"]
    summary = json.loads((export / "export.json").read_text())
    axis, val_fraction = summary["settings"]["axis"], summary["settings"]["val_fraction"]
    images, chosen = [], {}
    for source in summary["sources"]:
        if source["kind"] == "synthetic":
            if arm.synthetic:
                images += sorted((export / "images" / "train").glob(f"{source['name']}_a{axis}_s*.png"))
            continue
        slices = budget_slices(source["shape"][axis], arm.real_slices, val_fraction)
        chosen[source["name"]] = slices.tolist()
        images += [export / "images" / "train" / f"{source['name']}_a{axis}_s{i:04d}.png" for i in slices]
    missing = [p for p in images if not p.is_file()]
    if missing or not images:
        raise FileNotFoundError(f"{arm.dataset}: no training images in {export}" if not images else
                                f"{arm.dataset}: {len(missing)} images missing from {export}, e.g. {missing[0]}")
    out.mkdir(parents=True, exist_ok=True)
    data = yaml.safe_load((export / "data.yaml").read_text())
    data.update(train=str((out / "train.txt").resolve()))
    counts = {"train": len(images), "val": summary["images"]["val"], "test": summary["images"]["test"]}
    texts = {"train.txt": "".join(f"{p.resolve()}\n" for p in images), "data.yaml": yaml.safe_dump(data),
             "dataset.json": json.dumps({"arm": arm.dataset, "export": str(export), "images": counts,
                                         "real_slices": chosen}, indent=1)}
    for name, text in texts.items():  # dataset.json last
        with atomic_file(out / name) as staging:
            staging.write_text(text)
    return counts


def synthetic_images(data: Path, images: list[Path]) -> np.ndarray:
    """Which of `images`, training images of the dataset ``data`` (its ``data.yaml``), are slices of a pack.

    An image's source is its name before ``_a<axis>_s<index>`` (`subset_dataset`); the export's
    ``export.json`` (that of `data`'s folder, or the one its ``dataset.json`` names) says which
    sources are synthetic.

    Returns
    -------
    ndarray of bool, shape (len(images),)
    """
    folder = Path(data).parent
    export = folder
    if (folder / "dataset.json").is_file():
        export = Path(json.loads((folder / "dataset.json").read_text())["export"])
    summary = json.loads((export / "export.json").read_text())
    synthetic = {source["name"] for source in summary["sources"] if source["kind"] == "synthetic"}
    return np.array([Path(image).stem.rsplit("_a", 1)[0] in synthetic for image in images], dtype=bool)


def dataset_images(data: Path, arm: str) -> dict[str, int]:
    """Images per split of `arm`'s dataset folder ``data/<arm>``: its ``dataset.json`` or ``export.json``."""
    folder = Path(data) / arm
    record = folder / "dataset.json" if (folder / "dataset.json").is_file() else folder / "export.json"
    return json.loads(record.read_text())["images"]
