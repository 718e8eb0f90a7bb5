"""Dice scores of segmentations (paper eq. 12): foreground and matched-instance.

Definitions
-----------
Foreground Dice (`dice`)
    ``2 |P ∩ T| / (|P| + |T|)`` where ``P`` and ``T`` are the nonzero pixels
    (voxels) of the prediction and the truth. Two empty masks score 1.0 (a
    perfect prediction of "nothing"); one empty mask against a non-empty one
    scores 0.0.
Instances
    In a label image (integer, 0 = background) every distinct nonzero value is
    one instance, whether or not its pixels are connected.
Matching
    A predicted instance ``p`` and a true instance ``t`` are candidates when
    ``IoU(p, t) >= iou_threshold`` (default 0.5). Among the candidates a
    one-to-one assignment maximising the total IoU is found with the Hungarian
    algorithm (`scipy.optimize.linear_sum_assignment`), separately for each
    connected group of candidate pairs. With a threshold above 0.5 every
    instance has at most one candidate, so the matching is unique.
Matched-instance Dice
    Each matched pair scores ``2 |p ∩ t| / (|p| + |t|)``; every unmatched
    predicted instance (a false positive) and every unmatched true instance
    (a miss) scores 0.

    - *macro*: the mean over instances, counting each matched pair once and
      each unmatched instance once:
      ``sum(pair Dice) / (n_pred + n_true - n_matched)``;
    - *micro*: pooled over pixels,
      ``2 sum(|p ∩ t| over matched pairs) / (|P| + |T|)``, so the pixels of
      unmatched instances count in the denominator.

    Both are 1.0 when neither image has an instance.
Per image, per slice, per volume
    `dice_stats` compares two whole arrays, (H, W) images or (Z, Y, X)
    volumes (instances matched in 3D: "per volume"). `slice_dice_stats`
    compares each 2D slice of two volumes separately ("per slice": instances
    matched within each slice, so the label ids need not agree between slices).
    The sums in `DiceStats` add up: ``sum(stats)`` pools several images or
    slices, giving micro and macro scores over all of their pixels and
    instances; the mean of the per-image scores is the other way to average.

The overlap of all instance pairs comes from one joint histogram of
``(pred label, true label)`` pairs (a `numpy.bincount`), never from per-pair
comparisons of whole images.

`evaluate_folders` compares folders of label images and `EvaluationReport`
writes JSON, CSV and Markdown reports (the ``synthpack evaluate`` command).
"""

from __future__ import annotations

import csv
import io
import logging
import os
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ._shared.strict_json import dumps as strict_json
from .io.atomic import Output, atomic_directory
from .errors import SynthpackInputError
from .io import LABEL_IMAGE_SUFFIXES, read_label_image

logger = logging.getLogger(__name__)

__all__ = [
    "DiceStats",
    "InstanceMatches",
    "EvaluationReport",
    "dice",
    "match_instances",
    "dice_stats",
    "slice_dice_stats",
    "instance_dice",
    "evaluate_folders",
]

# Above this many (pred, truth) id pairs the joint histogram is built sparsely.
_DENSE_PAIRS = 1 << 22
# Above this label value ids are compacted by sorting instead of a lookup table.
_LOOKUP_MAX = 1 << 24


def dice(pred: np.ndarray, truth: np.ndarray) -> float:
    """Foreground Dice of two masks of one shape (nonzero = foreground).

    Parameters
    ----------
    pred, truth : ndarray, any dtype, same shape
        Masks or label images.

    Returns
    -------
    float
        ``2 |P ∩ T| / (|P| + |T|)`` in [0, 1]; 1.0 when both are empty.
    """
    pred, truth = np.asarray(pred), np.asarray(truth)
    _require_same_shape(pred, truth)
    p, t = pred != 0, truth != 0
    total = int(np.count_nonzero(p)) + int(np.count_nonzero(t))
    return 1.0 if total == 0 else 2.0 * int(np.count_nonzero(p & t)) / total


@dataclass(frozen=True)
class DiceStats:
    """The sums Dice scores are computed from; ``a + b`` and ``sum(...)`` pool them.

    Attributes
    ----------
    fg_intersection, fg_pred, fg_true : int
        Foreground pixels in both, in the prediction, in the truth.
    n_pred, n_true, n_matched : int
        Predicted, true and matched instances.
    matched_intersection : int
        Sum of ``|p ∩ t|`` over matched pairs, pixels.
    matched_dice_sum : float
        Sum of the Dice scores of the matched pairs.
    """

    fg_intersection: int = 0
    fg_pred: int = 0
    fg_true: int = 0
    n_pred: int = 0
    n_true: int = 0
    n_matched: int = 0
    matched_intersection: int = 0
    matched_dice_sum: float = 0.0

    def __add__(self, other: DiceStats) -> DiceStats:
        if not isinstance(other, DiceStats):
            return NotImplemented
        return DiceStats(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    def __radd__(self, other: object) -> DiceStats:
        if other == 0:  # sum() starts from 0
            return self
        return NotImplemented

    @property
    def dice(self) -> float:
        """Foreground Dice (1.0 when both are empty)."""
        total = self.fg_pred + self.fg_true
        return 1.0 if total == 0 else 2.0 * self.fg_intersection / total

    @property
    def instance_dice_macro(self) -> float:
        """Mean Dice over instances, unmatched ones scoring 0 (1.0 with no instances)."""
        units = self.n_pred + self.n_true - self.n_matched
        return 1.0 if units == 0 else self.matched_dice_sum / units

    @property
    def instance_dice_micro(self) -> float:
        """Pixel-pooled matched-instance Dice (1.0 with no instances)."""
        total = self.fg_pred + self.fg_true
        return 1.0 if total == 0 else 2.0 * self.matched_intersection / total

    @property
    def f1(self) -> float:
        """Detection F1 at the IoU threshold, ``2 n_matched / (n_pred + n_true)`` (1.0 with no instances)."""
        total = self.n_pred + self.n_true
        return 1.0 if total == 0 else 2.0 * self.n_matched / total

    def scores(self) -> dict[str, float]:
        """``dice``, ``instance_dice_macro``, ``instance_dice_micro`` and ``f1``."""
        return {"dice": self.dice, "instance_dice_macro": self.instance_dice_macro,
                "instance_dice_micro": self.instance_dice_micro, "f1": self.f1}


@dataclass(frozen=True)
class InstanceMatches:
    """Result of `match_instances`: the matched pairs and the unmatched ids.

    Attributes
    ----------
    pred_ids, true_ids : ndarray of int64, shape (M,)
        Labels of the matched pairs (``pred_ids[k]`` matches ``true_ids[k]``),
        sorted by true id.
    iou, dice : ndarray of float64, shape (M,)
        IoU and Dice of each pair.
    intersection : ndarray of int64, shape (M,)
        ``|p ∩ t|`` of each pair, pixels.
    unmatched_pred, unmatched_true : ndarray of int64
        Labels without a match.
    pred_area, true_area : int
        Total foreground pixels of prediction and truth.
    overlap_area : int
        Pixels in the foreground of both.
    """

    pred_ids: np.ndarray
    true_ids: np.ndarray
    iou: np.ndarray
    dice: np.ndarray
    intersection: np.ndarray
    unmatched_pred: np.ndarray
    unmatched_true: np.ndarray
    pred_area: int
    true_area: int
    overlap_area: int


def _require_same_shape(pred: np.ndarray, truth: np.ndarray) -> None:
    if pred.shape != truth.shape:
        raise SynthpackInputError(
            f"prediction and truth differ in shape ({pred.shape} vs {truth.shape}): "
            "compare label images of the same size"
        )


def _as_labels(array: np.ndarray, role: str) -> np.ndarray:
    array = np.asarray(array)
    if array.dtype == bool:
        return array.view(np.uint8)
    if not np.issubdtype(array.dtype, np.integer):
        raise SynthpackInputError(
            f"{role} labels have dtype {array.dtype}: give an integer label image (0 = background)"
        )
    if array.size and np.issubdtype(array.dtype, np.signedinteger) and array.min() < 0:
        raise SynthpackInputError(f"{role} labels hold negative values: use 0 for background and 1..N for instances")
    return array


def _compact(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted distinct values of a flat non-negative integer array, and each element's index into them."""
    top = int(values.max()) if values.size else 0
    if top < _LOOKUP_MAX:
        values = values.astype(np.intp, copy=False)
        present = np.bincount(values, minlength=1) > 0
        lookup = np.cumsum(present) - 1
        return np.flatnonzero(present), lookup[values]
    ids, index = np.unique(values, return_inverse=True)
    return ids, index.ravel()


def _overlaps(pred: np.ndarray, truth: np.ndarray):
    """Instance ids, areas and the sparse table of overlapping instance pairs.

    Returns ``(p_ids, p_area, t_ids, t_area, pi, ti, inter)``: ids (without 0)
    and their pixel counts, and for every pair of overlapping instances the
    index into ``p_ids``, into ``t_ids`` and the overlap in pixels.
    """
    p_ids, p_index = _compact(pred.ravel())
    t_ids, t_index = _compact(truth.ravel())
    n_p, n_t = len(p_ids), len(t_ids)
    key = p_index.astype(np.int64) * n_t + t_index
    if n_p * n_t <= _DENSE_PAIRS:
        joint = np.bincount(key, minlength=n_p * n_t)
        keys = np.flatnonzero(joint)
        counts = joint[keys]
    else:
        keys, counts = np.unique(key, return_counts=True)
    pi, ti = np.divmod(keys, n_t)
    p_area = np.bincount(p_index, minlength=n_p)
    t_area = np.bincount(t_index, minlength=n_t)
    # drop background (id 0 sorts first when present)
    p_skip = int(n_p > 0 and p_ids[0] == 0)
    t_skip = int(n_t > 0 and t_ids[0] == 0)
    both = (pi >= p_skip) & (ti >= t_skip)
    return (p_ids[p_skip:], p_area[p_skip:], t_ids[t_skip:], t_area[t_skip:],
            pi[both] - p_skip, ti[both] - t_skip, counts[both])


def _assign(pi: np.ndarray, ti: np.ndarray, iou: np.ndarray, n_p: int, n_t: int) -> np.ndarray:
    """Indices of the candidate pairs kept by a maximum-IoU one-to-one assignment."""
    if len(pi) == 0:
        return np.zeros(0, dtype=np.int64)
    graph = coo_matrix((np.ones(len(pi)), (pi, n_p + ti)), shape=(n_p + n_t,) * 2)
    _, component = connected_components(graph, directed=False)
    edge_component = component[pi]
    edges_per_component = np.bincount(edge_component)
    single = edges_per_component[edge_component] == 1
    kept = [np.flatnonzero(single)]
    for c in np.unique(edge_component[~single]):
        edges = np.flatnonzero(edge_component == c)
        rows, row_of = np.unique(pi[edges], return_inverse=True)
        cols, col_of = np.unique(ti[edges], return_inverse=True)
        matrix = np.zeros((len(rows), len(cols)))
        edge_at = np.full((len(rows), len(cols)), -1, dtype=np.int64)
        matrix[row_of, col_of] = iou[edges]
        edge_at[row_of, col_of] = edges
        assigned_rows, assigned_cols = linear_sum_assignment(matrix, maximize=True)
        chosen = edge_at[assigned_rows, assigned_cols]
        kept.append(chosen[chosen >= 0])
    return np.sort(np.concatenate(kept))


def match_instances(pred: np.ndarray, truth: np.ndarray, *, iou_threshold: float = 0.5) -> InstanceMatches:
    """Match the instances of two label images of one shape by IoU (see the module docstring).

    Parameters
    ----------
    pred, truth : ndarray of int (or bool), shape (H, W) or (Z, Y, X)
        Label images, 0 = background.
    iou_threshold : float in (0, 1]
        Minimum IoU of a matched pair.

    Returns
    -------
    InstanceMatches
    """
    if not 0 < iou_threshold <= 1:
        raise SynthpackInputError(f"iou_threshold must be in (0, 1], got {iou_threshold}")
    pred, truth = _as_labels(pred, "predicted"), _as_labels(truth, "true")
    _require_same_shape(pred, truth)
    p_ids, p_area, t_ids, t_area, pi, ti, inter = _overlaps(pred, truth)
    overlap_area = int(inter.sum())
    union = p_area[pi] + t_area[ti] - inter
    iou = inter / union
    candidate = iou >= iou_threshold
    pi, ti, inter, iou = pi[candidate], ti[candidate], inter[candidate], iou[candidate]
    keep = _assign(pi, ti, iou, len(p_ids), len(t_ids))
    pi, ti, inter, iou = pi[keep], ti[keep], inter[keep], iou[keep]
    order = np.argsort(ti, kind="stable")
    pi, ti, inter, iou = pi[order], ti[order], inter[order], iou[order]
    pair_dice = 2.0 * inter / (p_area[pi] + t_area[ti])
    return InstanceMatches(
        pred_ids=p_ids[pi].astype(np.int64), true_ids=t_ids[ti].astype(np.int64), iou=iou.astype(np.float64),
        dice=pair_dice.astype(np.float64), intersection=inter.astype(np.int64),
        unmatched_pred=np.delete(p_ids, pi).astype(np.int64), unmatched_true=np.delete(t_ids, ti).astype(np.int64),
        pred_area=int(p_area.sum()), true_area=int(t_area.sum()), overlap_area=overlap_area,
    )


def dice_stats(pred: np.ndarray, truth: np.ndarray, *, iou_threshold: float = 0.5) -> DiceStats:
    """Foreground and matched-instance sums of two whole label images or volumes.

    Parameters
    ----------
    pred, truth : ndarray of int (or bool), shape (H, W) or (Z, Y, X)
        Label images, 0 = background; 3D instances are matched in 3D.
    iou_threshold : float
        Minimum IoU of a matched pair.
    """
    matches = match_instances(pred, truth, iou_threshold=iou_threshold)
    return DiceStats(
        fg_intersection=matches.overlap_area, fg_pred=matches.pred_area, fg_true=matches.true_area,
        n_pred=len(matches.pred_ids) + len(matches.unmatched_pred),
        n_true=len(matches.true_ids) + len(matches.unmatched_true),
        n_matched=len(matches.pred_ids), matched_intersection=int(matches.intersection.sum()),
        matched_dice_sum=float(matches.dice.sum()),
    )


def slice_dice_stats(pred: np.ndarray, truth: np.ndarray, *, axis: int = 0,
                     iou_threshold: float = 0.5) -> list[DiceStats]:
    """`dice_stats` of every 2D slice of two (Z, Y, X) volumes along `axis`.

    Returns
    -------
    list of DiceStats
        One per slice, in order; ``sum(result)`` pools them.
    """
    pred, truth = np.asarray(pred), np.asarray(truth)
    _require_same_shape(pred, truth)
    if pred.ndim != 3:
        raise SynthpackInputError(f"per-slice scores need 3D volumes, got {pred.ndim}D arrays")
    if axis not in (0, 1, 2):
        raise SynthpackInputError(f"axis must be 0, 1 or 2, got {axis}")
    pred, truth = np.moveaxis(pred, axis, 0), np.moveaxis(truth, axis, 0)
    return [dice_stats(p, t, iou_threshold=iou_threshold) for p, t in zip(pred, truth)]


def instance_dice(pred: np.ndarray, truth: np.ndarray, *, average: str = "macro", per: str = "image",
                  axis: int = 0, iou_threshold: float = 0.5) -> float:
    """Matched-instance Dice of two label images or volumes.

    Parameters
    ----------
    pred, truth : ndarray of int, shape (H, W) or (Z, Y, X)
        Label images, 0 = background.
    average : {"macro", "micro"}
        Mean over instances, or pooled over pixels (see the module docstring).
    per : {"image", "slice"}
        ``"image"`` matches over the whole array (a 3D array: per volume);
        ``"slice"`` matches within each 2D slice of a volume along `axis` and
        pools the slices.
    axis : int
        Slicing axis for ``per="slice"``.
    iou_threshold : float
        Minimum IoU of a matched pair.
    """
    if average not in ("macro", "micro"):
        raise SynthpackInputError(f"average must be 'macro' or 'micro', got {average!r}")
    if per == "image":
        stats = dice_stats(pred, truth, iou_threshold=iou_threshold)
    elif per == "slice":
        stats = sum(slice_dice_stats(pred, truth, axis=axis, iou_threshold=iou_threshold), DiceStats())
    else:
        raise SynthpackInputError(f"per must be 'image' or 'slice', got {per!r}")
    return stats.instance_dice_macro if average == "macro" else stats.instance_dice_micro


# --------------------------------------------------------------------------- #
# Folders of label images
# --------------------------------------------------------------------------- #


def _label_files(folder: Path, role: str) -> dict[str, Path]:
    if not folder.is_dir():
        raise SynthpackInputError(f"{role} folder {folder} does not exist: give a folder of label images")
    files: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.name.startswith(".") or path.suffix.lower() not in LABEL_IMAGE_SUFFIXES:
            continue
        if path.stem in files:
            raise SynthpackInputError(
                f"{role} folder {folder} holds two label images named {path.stem!r} "
                f"({files[path.stem].name}, {path.name}): keep one"
            )
        files[path.stem] = path
    if not files:
        raise SynthpackInputError(
            f"{role} folder {folder} holds no label images ({', '.join(LABEL_IMAGE_SUFFIXES)})"
        )
    return files


#: Columns of a report row, in CSV order.
_ROW_COUNTS = ("n_true", "n_pred", "n_matched")
_SCORES = ("dice", "instance_dice_macro", "instance_dice_micro", "f1")


def _row(name: str, index: int | None, stats: DiceStats) -> dict:
    row = {"file": name, "slice": "" if index is None else index,
           "n_true": stats.n_true, "n_pred": stats.n_pred, "n_matched": stats.n_matched}
    row.update(stats.scores())
    return row


#: An evaluation report folder: an earlier report (``evaluation.json``) is replaced, anything else is refused.
EVALUATION_OUTPUT = Output("evaluation report", marker="evaluation.json")


@dataclass
class EvaluationReport:
    """Scores of a folder comparison: one row per file (or per slice) and a summary.

    Attributes
    ----------
    rows : list of dict
        ``file`` (name without extension), ``slice`` (index, or ``""`` for a
        whole file), ``n_true``, ``n_pred``, ``n_matched`` and the scores
        ``dice``, ``instance_dice_macro``, ``instance_dice_micro``, ``f1``.
    stats : list of DiceStats
        The sums behind each row.
    settings : dict
        Folders, ``per``, ``axis`` and ``iou_threshold``.
    """

    rows: list[dict]
    stats: list[DiceStats]
    settings: dict

    @property
    def summary(self) -> dict:
        """Counts, pooled scores (all rows' pixels and instances) and the mean of the rows' scores."""
        pooled = sum(self.stats, DiceStats())
        return {
            "n_files": len({row["file"] for row in self.rows}),
            "n_rows": len(self.rows),
            "n_true": pooled.n_true, "n_pred": pooled.n_pred, "n_matched": pooled.n_matched,
            "pooled": pooled.scores(),
            "mean_of_rows": {key: float(np.mean([row[key] for row in self.rows])) for key in _SCORES},
        }

    def to_dict(self) -> dict:
        """JSON-able: settings, summary, rows."""
        return {"settings": self.settings, "summary": self.summary, "rows": self.rows}

    def markdown(self, rows: bool = True) -> str:
        """Summary table, then (if `rows`) the table of every row."""
        summary = self.summary
        lines = [
            "# Dice evaluation",
            "",
            f"prediction `{self.settings['pred']}` vs truth `{self.settings['truth']}`; "
            f"rows per {self.settings['per']}, IoU threshold {self.settings['iou_threshold']}; "
            f"{summary['n_files']} files, {summary['n_rows']} rows; "
            f"{summary['n_true']} true, {summary['n_pred']} predicted, {summary['n_matched']} matched instances",
            "",
            "| average | " + " | ".join(_SCORES) + " |",
            "|---|" + "---|" * len(_SCORES),
            "| pooled over rows | " + " | ".join(f"{summary['pooled'][k]:.4f}" for k in _SCORES) + " |",
            "| mean of rows | " + " | ".join(f"{summary['mean_of_rows'][k]:.4f}" for k in _SCORES) + " |",
        ]
        if rows:
            lines += ["", "## Rows", "",
                      "| file | slice | " + " | ".join(_ROW_COUNTS + _SCORES) + " |",
                      "|---|---|" + "---|" * (len(_ROW_COUNTS) + len(_SCORES))]
            for row in self.rows:
                lines.append(f"| {row['file']} | {row['slice']} | " + " | ".join(
                    [str(row[k]) for k in _ROW_COUNTS] + [f"{row[k]:.4f}" for k in _SCORES]) + " |")
        return "\n".join(lines) + "\n"

    def csv(self) -> str:
        """The rows as CSV text with a header line."""
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=["file", "slice", *_ROW_COUNTS, *_SCORES], lineterminator="\n")
        writer.writeheader()
        writer.writerows(self.rows)
        return buffer.getvalue()

    def write(self, out: str | os.PathLike, *, overwrite: bool = False) -> dict[str, Path]:
        """Write ``evaluation.json``, ``evaluation.csv`` and ``evaluation.md`` into the folder `out`, atomically.

        An earlier report there is replaced; with `overwrite` a folder holding
        anything else receives the report's files and keeps its other files.
        """
        out = Path(out)
        texts = {"json": strict_json(self.to_dict(), indent=1), "csv": self.csv(), "md": self.markdown()}
        with atomic_directory(out, EVALUATION_OUTPUT, overwrite=overwrite) as staging:
            for kind, text in texts.items():
                (staging / f"evaluation.{kind}").write_text(text)
        return {kind: out / f"evaluation.{kind}" for kind in texts}


def evaluate_folders(pred: str | os.PathLike, truth: str | os.PathLike, *, per: str = "slice", axis: int = 0,
                     iou_threshold: float = 0.5) -> EvaluationReport:
    """Score the label images of `pred` against those of `truth`.

    Layout: each folder holds label images (``.png``, ``.tif``/``.tiff`` or
    ``.npy``; 0 = background, one integer id per instance), 2D slices (H, W)
    or 3D volumes (Z, Y, X). Files are paired by name without extension
    (``a.png`` in `pred` pairs with ``a.tif`` in `truth`) and a pair must have
    one shape. Every truth file needs a prediction; predictions without a
    truth file are ignored (logged).

    Parameters
    ----------
    pred, truth : path-like
        The two folders.
    per : {"slice", "volume"}
        ``"slice"``: one row per 2D slice of a 3D file (slices along `axis`,
        instances matched within each slice, so ids need not agree between
        slices); ``"volume"``: one row per file, 3D instances matched in 3D.
        A 2D file is one row either way.
    axis : int
        Slicing axis of 3D files for ``per="slice"``.
    iou_threshold : float
        Minimum IoU of a matched instance pair.

    Returns
    -------
    EvaluationReport
    """
    if per not in ("slice", "volume"):
        raise SynthpackInputError(f"per must be 'slice' or 'volume', got {per!r}")
    pred, truth = Path(pred), Path(truth)
    truth_files = _label_files(truth, "truth")
    pred_files = _label_files(pred, "prediction")
    missing = sorted(set(truth_files) - set(pred_files))
    if missing:
        shown = ", ".join(missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise SynthpackInputError(
            f"{len(missing)} truth file(s) have no prediction in {pred} ({shown}): give one label image "
            "per truth file, with the same name (any of the supported extensions)"
        )
    extra = sorted(set(pred_files) - set(truth_files))
    if extra:
        logger.info("%d prediction(s) without a truth file ignored (%s)", len(extra), ", ".join(extra[:5]))
    rows: list[dict] = []
    stats: list[DiceStats] = []
    for name, truth_path in truth_files.items():
        t = read_label_image(truth_path)
        p = read_label_image(pred_files[name])
        if p.shape != t.shape:
            raise SynthpackInputError(
                f"{pred_files[name].name} has shape {p.shape} but {truth_path.name} has {t.shape}: "
                "predictions must have the shape of their truth"
            )
        if per == "slice" and t.ndim == 3:
            for index, s in enumerate(slice_dice_stats(p, t, axis=axis, iou_threshold=iou_threshold)):
                rows.append(_row(name, index, s))
                stats.append(s)
        else:
            s = dice_stats(p, t, iou_threshold=iou_threshold)
            rows.append(_row(name, None, s))
            stats.append(s)
    settings = {"pred": str(pred), "truth": str(truth), "per": per, "axis": axis, "iou_threshold": iou_threshold}
    return EvaluationReport(rows, stats, settings)
