"""What a pack shows, a tube or an interior crop of the source, and how many grains it pours for it."""

from __future__ import annotations

import functools
import logging

from ..errors import SynthpackInputError
from ..library.core import ParticleLibrary
from .config import PackConfig

logger = logging.getLogger(__name__)

__all__ = ["resolve_pack", "resolve_view", "warn_tube"]


def resolve_view(library: ParticleLibrary, config: PackConfig) -> str:
    """What a pack of `config` shows: ``"tube"`` or ``"interior"`` (``reconstruct.view``, `ReconstructConfig.view_of`).

    ``auto`` for a source scan that is an interior crop is ``interior``, unless the grains
    (``pour.n_particles``; ``auto`` pours as many as a crop needs) are too few for one or the
    given ``pour.tube_radius`` too narrow: then ``tube``, with a line that says why.

    Raises
    ------
    SynthpackInputError
        For ``view: interior`` with too few grains for a crop.
    """
    view = config.reconstruct.view_of(library.statistics)
    if view == "interior":
        try:
            config.pour.tube(library, interior=True)
        except SynthpackInputError as error:
            if config.reconstruct.view != "auto":
                raise
            grains, needed = config.pour.grains(library, interior=True), config.pour.crop_grains(library)
            warn_tube(str(error), f"{grains} grains are too few for an interior crop ({needed} or more: --n-particles)"
                      if grains < needed else "the given tube is too narrow for an interior crop (-v says why)")
            return "tube"
    return view


def resolve_pack(library: ParticleLibrary, config: PackConfig) -> tuple[PackConfig, str]:
    """`config` with its grain count resolved (`PourConfig.grains`) for the view it shows (`resolve_view`).

    Returns
    -------
    config : PackConfig
        ``pour.n_particles`` a number: as given, or for ``auto`` the count of a tube or of an interior crop.
    view : str
        ``"tube"`` or ``"interior"``.
    """
    view = resolve_view(library, config)
    grains = config.pour.grains(library, interior=view == "interior")
    if grains != config.pour.n_particles:
        _say_once(f"pour.n_particles auto: {grains} grains, for "
                  + ("an interior crop of the source" if view == "interior" else "a tube"))
    return config.replace(pour={"n_particles": grains}), view


@functools.cache
def _say_once(line: str) -> None:
    """Log `line` at INFO, once per process (not once per pack)."""
    logger.info(line)


def warn_tube(why: str, short: str) -> None:
    """Say (at INFO, `short` in one line; `why` at DEBUG) that ``view: auto`` shows the tube for an interior-crop
    source."""
    _say_once(f"view auto: the tube: {short}")
    logger.debug("The source scan is an interior crop, but the pack shows the tube: %s", why)
