"""Training compute per arm: the same number of optimizer steps for every arm, or the paper's fixed epochs.

Ultralytics trains by epochs, so under the paper's rule (``train.compute: fixed_epochs``) an
arm with more training images takes more optimizer steps: ``large+syn`` (205 images) 2.3
times those of ``large`` (90), and a gain from packs cannot be told from a gain from steps.

Under ``train.compute: equal_steps`` (the default) every arm of a run sees the same number of
training images B, ``train.images_seen`` (default: the largest arm's training images times
``train.epochs``). An arm of n images trains ``ceil(B / n)`` epochs, so it sees B images up
to less than one of its epochs, and takes ``steps = images seen / batch`` steps (batches of
``train.batch``; Ultralytics accumulates gradients up to its nominal batch ``nbs`` before an
optimizer update, the same for every arm). Scaling epochs was chosen over sampling with
replacement: every arm's epoch still shows each of its images once, as Ultralytics means it,
and its ``fraction`` option keeps working.

Options counted in epochs (`EPOCH_COUNTED_OPTIONS`) are read as epochs of the largest arm
(the *reference epoch*: n_max images seen) and multiplied by ``n_max / n`` for an arm of n
images, so that warm-up, the mosaic-free end and the early-stopping patience are the same
share of every arm's steps; every arm validates once per reference epoch (every n_max
images seen: `ArmPlan.val_every`), so every arm picks its model among as many checkpoints,
taken at the same steps.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from synthpack.errors import SynthpackInputError

__all__ = ["COMPUTE_MODES", "EPOCH_COUNTED_OPTIONS", "ArmPlan", "effective_images", "plan_compute",
           "scale_epoch_options"]

#: ``train.compute`` values and what they mean, in the report's words.
COMPUTE_MODES = {
    "equal_steps": "equal steps: every arm sees the same number of training images, its epochs scaled "
                   "from its training-set size",
    "fixed_epochs": "fixed epochs (the paper's rule): every arm trains the same epochs, so an arm with more "
                    "images takes more steps and its differences mix data with compute",
}
#: Ultralytics ``YOLO.train`` options counted in epochs, scaled with an arm's epochs under equal steps.
EPOCH_COUNTED_OPTIONS = ("close_mosaic", "warmup_epochs", "patience")


@dataclass(frozen=True)
class ArmPlan:
    """How long one arm trains.

    Attributes
    ----------
    compute : str
        A key of `COMPUTE_MODES`.
    images : int
        Training images of one epoch (after Ultralytics' ``fraction``).
    epochs : int
    batch : int
        Images per batch.
    epoch_scale : float
        This arm's epochs per reference epoch (``n_max / n``; 1 under fixed epochs): the
        factor of its `EPOCH_COUNTED_OPTIONS`.
    val_every : int
        Training images seen between two validations.
    """

    compute: str
    images: int
    epochs: int
    batch: int
    epoch_scale: float
    val_every: int

    @property
    def images_seen(self) -> int:
        """Training images seen over the whole training (``epochs * images``)."""
        return self.epochs * self.images

    @property
    def steps(self) -> float:
        """Optimizer steps in batches: ``images_seen / batch``."""
        return self.images_seen / self.batch

    @property
    def validation_epochs(self) -> list[int]:
        """The epochs (1-based) after which it validates: those whose images seen pass a multiple of
        `val_every`, and the last."""
        due = [e for e in range(1, self.epochs + 1)
               if e * self.images // self.val_every > (e - 1) * self.images // self.val_every]
        return due if due and due[-1] == self.epochs else [*due, self.epochs]

    def to_dict(self) -> dict:
        """JSON-able dict of the fields and of ``images_seen`` and ``steps``."""
        return {**asdict(self), "images_seen": self.images_seen, "steps": self.steps}


def effective_images(n_images: int, fraction: float | int = 1.0) -> int:
    """Training images Ultralytics uses of `n_images` with its ``fraction`` option.

    A float keeps ``max(1, round(n * fraction))`` images, an int that many (at most all),
    as ``ultralytics.data.base.BaseDataset.get_img_files`` does.
    """
    count = fraction if isinstance(fraction, int) and not isinstance(fraction, bool) else max(
        1, round(n_images * fraction))
    return min(count, n_images)


def plan_compute(settings, sizes: dict[str, int]) -> dict[str, ArmPlan]:
    """The epochs of every arm of a run from its training-set size.

    Parameters
    ----------
    settings : training.train.TrainSettings
        ``compute`` (checked by `TrainSettings`), ``images_seen``, ``epochs``, ``batch`` and
        ``options["fraction"]`` are read.
    sizes : dict
        Arm name -> training images of its dataset (before ``fraction``).

    Returns
    -------
    dict
        Arm name -> `ArmPlan`, in the order of `sizes`.

    Raises
    ------
    SynthpackInputError
        If ``settings.images_seen`` is less than one epoch of the largest arm.
    """
    fraction = settings.options.get("fraction", 1.0)
    images = {arm: effective_images(n, fraction) for arm, n in sizes.items()}
    if not images:
        return {}
    if settings.compute == "fixed_epochs":
        return {arm: ArmPlan("fixed_epochs", n, settings.epochs, settings.batch, 1.0, n) for arm, n in images.items()}
    largest = max(images.values())
    budget = settings.images_seen or largest * settings.epochs
    if budget < largest:
        arm = max(images, key=images.get)
        raise SynthpackInputError(f"train.images_seen {budget} is less than one epoch of arm {arm} ({largest} "
                                  f"images): raise it to at least {largest}")
    return {arm: ArmPlan("equal_steps", n, math.ceil(budget / n), settings.batch, largest / n, largest)
            for arm, n in images.items()}


def scale_epoch_options(options: dict, defaults: dict, scale: float) -> dict:
    """`EPOCH_COUNTED_OPTIONS` of `options` (else of `defaults`) multiplied by `scale`.

    Parameters
    ----------
    options : dict
        ``YOLO.train`` keywords of the config.
    defaults : dict
        Ultralytics' defaults (``ultralytics.cfg.DEFAULT_CFG_DICT``) for those not in `options`.
    scale : float
        `ArmPlan.epoch_scale`.

    Returns
    -------
    dict
        Each of `EPOCH_COUNTED_OPTIONS`: ``warmup_epochs`` a float, the others whole epochs
        (rounded; ``patience`` up).
    """
    values = {key: options.get(key, defaults[key]) for key in EPOCH_COUNTED_OPTIONS}
    return {"close_mosaic": round(values["close_mosaic"] * scale),
            "warmup_epochs": float(values["warmup_epochs"]) * scale,
            "patience": math.ceil(values["patience"] * scale)}
