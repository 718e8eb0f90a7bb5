"""Length units and voxel sizes: unit spellings, conversion between length units, and the choice of
`read_scan`'s voxel size among the argument and the files' metadata.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import SynthpackInputError
from ..scan.core import validate_voxel_size
from ._base import Metadata, VoxelSize

logger = logging.getLogger(__name__)


# Length of one unit in micrometres, to convert between known length units.
_MICROMETRES = {"nm": 1e-3, "um": 1.0, "mm": 1e3, "cm": 1e4, "m": 1e6}

_UNIT_ALIASES = {
    "µm": "um", "μm": "um", "\\u00b5m": "um", "micron": "um", "microns": "um",
    "micrometer": "um", "micrometre": "um", "micrometers": "um", "micrometres": "um",
    "millimeter": "mm", "millimetre": "mm", "millimeters": "mm", "millimetres": "mm",
    "nanometer": "nm", "nanometre": "nm", "centimeter": "cm", "centimetre": "cm",
    "meter": "m", "metre": "m", "pixel": "px", "pixels": "px", "voxel": "px", "": "px",
}


def _attribute_voxel_size(voxel_size: object, unit: object, path: Path) -> Metadata:
    """Validated voxel size and unit from store attributes, or (None, None)."""
    if voxel_size is None or unit is None:
        return None, None
    try:
        size = validate_voxel_size(voxel_size)
    except SynthpackInputError as exc:
        try:  # plain numbers, not np.float32(...)
            voxel_size = np.asarray(voxel_size, dtype=float).tolist()
        except (TypeError, ValueError):
            pass
        raise SynthpackInputError(
            f"{path} records an invalid voxel size {voxel_size!r}: fix its metadata "
            "or pass the voxel size explicitly"
        ) from exc
    unit = _normalise_unit(str(unit))
    return (None, None) if unit == "px" else (size, unit)


def _normalise_unit(unit: str) -> str:
    """Canonical spelling of a length unit: ``"um"`` for micron/µm, ``"px"`` for none."""
    key = unit.strip()
    return _UNIT_ALIASES.get(key.lower(), _UNIT_ALIASES.get(key, key))


def convert_voxel_size(size: VoxelSize, unit: str, to: str) -> VoxelSize | None:
    """Voxel size `size` from `unit` into `to`, or None if either is not a known length unit (nm, um, mm, cm, m)."""
    if unit not in _MICROMETRES or to not in _MICROMETRES:
        return None
    factor = _MICROMETRES[unit] / _MICROMETRES[to]
    return tuple(v * factor for v in size)  # type: ignore[return-value]


def _resolve_voxel_size(
    voxel_size: float | tuple[float, ...] | None,
    unit: str | None,
    tomo_meta: Metadata,
    label_meta: Metadata,
) -> tuple[VoxelSize, str, str]:
    """Choose ``(voxel_size, unit, where it came from)`` for read_scan (see its Notes)."""
    unit = None if unit is None else _normalise_unit(unit)
    meta_size, meta_unit = tomo_meta if tomo_meta[0] is not None else label_meta
    origin = "tomogram metadata" if tomo_meta[0] is not None else "labels metadata"
    if tomo_meta[0] is not None and label_meta[0] is not None and (
        tomo_meta[1] != label_meta[1] or not np.allclose(tomo_meta[0], label_meta[0])
    ):
        logger.info("voxel size in the tomogram metadata (%s %s) and the labels metadata "
                    "(%s %s) differ; using the tomogram's", *tomo_meta, *label_meta)
    if voxel_size is not None:
        size = validate_voxel_size(voxel_size)
        unit = unit or meta_unit or "um"
        if meta_size is not None and (unit != meta_unit or not np.allclose(size, meta_size)):
            logger.info("voxel size %s %s given explicitly overrides %s %s from the %s",
                        size, unit, meta_size, meta_unit, origin)
        return size, unit, "argument"
    if meta_size is not None:
        if unit is None or unit == meta_unit:
            return meta_size, meta_unit, origin
        converted = convert_voxel_size(meta_size, meta_unit, unit)
        if converted is not None:
            return converted, unit, origin
        logger.info("unit %r given explicitly overrides %r from the %s (no conversion "
                    "between them is known)", unit, meta_unit, origin)
        return meta_size, unit, origin
    if unit is not None:
        logger.info("unit %r ignored: no voxel size was given or recorded", unit)
    return (1.0, 1.0, 1.0), "px", "default"

