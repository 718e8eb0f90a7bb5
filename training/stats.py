"""Paired bootstrap confidence intervals of a difference in pooled foreground Dice (NumPy only).

Two training arms scored on the same test slices with the same training seeds give,
per seed ``s`` and slice ``i``, the foreground pixel counts ``(intersection, pred,
true)`` of each arm. An arm's score is the mean over seeds of its Dice pooled over
the slices, ``2 sum_i I / (sum_i P + sum_i T)`` (the Dice of the report's tables).
`paired_bootstrap` resamples seeds and slices with replacement, the SAME seeds and
slices for both arms (the pairing), and takes the 2.5 and 97.5 percentiles of the
resampled differences: an interval that holds both the slice-to-slice variation of
the test scan and the seed-to-seed variation of training.

The matched-instance F1 pools the same way from instance counts ``(matched, pred, true)``,
``2 sum_i M / (sum_i P + sum_i T)``, so `pooled_dice` and `paired_bootstrap` give its
intervals too, from those counts.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["BOOTSTRAP_SAMPLES", "Difference", "paired_bootstrap", "pooled_dice"]

#: Bootstrap resamples per interval.
BOOTSTRAP_SAMPLES = 2000


def pooled_dice(counts: np.ndarray) -> np.ndarray:
    """Dice pooled over the slices (axis -2) of ``counts[..., slice, (intersection, pred, true)]``.

    Parameters
    ----------
    counts : ndarray, shape (..., N, 3)
        Foreground pixels in both, in the prediction and in the truth, per slice.

    Returns
    -------
    ndarray of float64, shape (...)
        1 where both masks are empty (as `synthpack.metrics.dice`).
    """
    sums = np.asarray(counts, dtype=np.float64).sum(axis=-2)
    total = sums[..., 1] + sums[..., 2]
    return np.where(total > 0, 2.0 * sums[..., 0] / np.where(total > 0, total, 1.0), 1.0)


@dataclass(frozen=True)
class Difference:
    """``a - b`` of two arms' mean pooled Dice, with its bootstrap interval.

    Attributes
    ----------
    difference : float
        On the data as they are (fraction, not %).
    low, high : float
        The bounds of the interval.
    level : float
        Its confidence level, e.g. 0.95.
    n_seeds, n_slices : int
        The paired seeds and slices it was computed from.
    """

    difference: float
    low: float
    high: float
    level: float
    n_seeds: int
    n_slices: int

    @property
    def excludes_zero(self) -> bool:
        """Whether the interval lies wholly above or below 0."""
        return self.low > 0 or self.high < 0

    def to_dict(self) -> dict:
        """JSON-able dict of every field."""
        return asdict(self)


def paired_bootstrap(a: np.ndarray, b: np.ndarray, *, n_samples: int = BOOTSTRAP_SAMPLES, level: float = 0.95,
                     seed: int = 0) -> Difference:
    """The difference of two arms' mean pooled Dice and its paired bootstrap interval.

    Parameters
    ----------
    a, b : ndarray, shape (S, N, 3)
        Per training seed (the same seeds, in the same order) and test slice (the same
        slices, in the same order): foreground pixels in both, in the prediction, in
        the truth (`training.evaluate.score`'s ``slices``).
    n_samples : int
        Bootstrap resamples.
    level : float
        Confidence level, in (0, 1).
    seed : int
        Seed of the resampling: the same inputs and seed give the same interval.

    Returns
    -------
    Difference

    Raises
    ------
    ValueError
        If the two arms do not have the same seeds and slices.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3 or 0 in a.shape[:2]:
        raise ValueError(f"paired arms need counts of one shape (seeds, slices, 3), got {a.shape} and {b.shape}")
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    n_seeds, n_slices = a.shape[:2]
    rng = np.random.default_rng(seed)
    seeds = rng.integers(0, n_seeds, size=(n_samples, n_seeds))
    slices = rng.integers(0, n_slices, size=(n_samples, n_slices))
    picked = (seeds[:, :, None], slices[:, None, :])  # (n_samples, n_seeds, n_slices)
    samples = pooled_dice(a[picked]).mean(axis=1) - pooled_dice(b[picked]).mean(axis=1)
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(samples, [tail, 100 - tail])
    observed = float(pooled_dice(a).mean() - pooled_dice(b).mean())
    return Difference(observed, float(low), float(high), level, n_seeds, n_slices)
