"""A dataset's ``transform``: artefact transforms on the NumPy slice or patch, then the item's callables."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..artefacts import Compose as ArtefactCompose
from ..artefacts import Transform as ArtefactTransform
from .._shared.seeds import generator
from ..errors import SynthpackInputError
from .targets import Item

__all__ = ["SliceTransforms"]


class SliceTransforms:
    """The ``transform`` argument of a slice (or patch) dataset, split by what each part acts on.

    Parameters
    ----------
    transform : callable, artefact transform or list of them, optional
        `synthpack.artefacts` transforms (listed first) act on the float32
        NumPy slice (or 3D patch); any other callable is called on the item,
        in order, as `form` says.
    form : str
        How the dataset calls the other callables, for error messages: the
        slice datasets' ``image, target = transform(image, target)`` or the
        patch dataset's ``item = transform(item)``.

    Attributes
    ----------
    artefacts : list
        The artefact transforms, in order.
    callables : list
        The other callables, in order.
    """

    def __init__(self, transform: Any, form: str = "image, target = transform(image, target)") -> None:
        self.artefacts: list = []
        self.callables: list = []
        if transform is None:
            entries = []
        elif isinstance(transform, (list, tuple)):
            entries = list(transform)
        else:
            entries = [transform]
        for entry in entries:
            if isinstance(entry, (ArtefactTransform, ArtefactCompose)):
                if self.callables:
                    raise SynthpackInputError(
                        f"artefact transform {entry!r} comes after a transform called as {form}: artefacts "
                        "act on the raw slice or patch, so list them first, e.g. "
                        "transform=[GaussianNoise(std=0.05), <the other transforms>]"
                    )
                self.artefacts.append(entry)
            elif callable(entry):
                self.callables.append(entry)
            else:
                raise SynthpackInputError(
                    f"transform {entry!r} is neither a synthpack.artefacts transform nor a callable "
                    f"{form}: pass one of those, or a list of them"
                )

    def apply_artefacts(self, image: np.ndarray, seed: int, *key: int) -> np.ndarray:
        """The artefact transforms applied in order to the (H, W) slice or (D, H, W) patch `image`.

        Their random draws come from one generator on the dataset seed's ``"augment"``
        stream below `key` (the item's ``epoch, volume, axis, slice`` for a slice), so
        an item is the same in any process.
        """
        if not self.artefacts:
            return image
        rng = generator(seed, "augment", *key)
        for artefact in self.artefacts:
            image = artefact(image, rng)
        return image

    def __call__(self, image: Any, target: dict[str, Any]) -> Item:
        """The ``(image, target)`` callables applied in order."""
        sample: Item = (image, target)
        for transform in self.callables:
            sample = transform(*sample)
        return sample
