"""OME-NGFF 0.5 metadata of 3D images: written for packs, read for any OME-Zarr input.

An OME-Zarr image (NGFF 0.5, on Zarr v3) is a Zarr group whose attributes hold
``{"ome": {"version": "0.5", "multiscales": [...]}}``: the axes ``z, y, x`` (type
``space``, with the length unit spelled as NGFF wants it, e.g. ``"micrometer"``) and
one dataset per resolution level, each a Zarr array of the group with its
``coordinateTransformations``: the voxel size of that level (``scale``, z first) and,
for levels downsampled by a mean, the offset of their voxel centres (``translation``).
A label image adds ``image-label`` metadata, and the image's group ``labels`` lists
its label images under ``ome.labels``.

This module only builds and reads these attribute dictionaries; the pack's store
that carries them is `synthpack.store.zarr_pack`, and `synthpack.io` reads OME-Zarr
inputs with :func:`full_resolution`.

References: https://ngff.openmicroscopy.org/0.5/
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..errors import SynthpackInputError

__all__ = ["NGFF_VERSION", "AXES", "image_attributes", "labels_attributes", "label_names", "full_resolution"]

#: The NGFF version synthpack writes.
NGFF_VERSION = "0.5"
#: The axes of every volume, in array order.
AXES = ("z", "y", "x")
# synthpack's length units -> NGFF's (UDUNITS-2) names; "px" (no physical unit) has none.
_NGFF_UNITS = {"nm": "nanometer", "um": "micrometer", "mm": "millimeter", "cm": "centimeter", "m": "meter"}


def image_attributes(
    name: str,
    voxel_sizes: Sequence[Sequence[float]],
    unit: str,
    *,
    translations: Sequence[Sequence[float]] | None = None,
    method: str | None = None,
    label_source: str | None = None,
) -> dict[str, Any]:
    """The ``ome`` attributes of a 3D multiscales image whose levels are the arrays ``"0"``, ``"1"``, ...

    Parameters
    ----------
    name : str
        Name of the image (``multiscales[0].name``).
    voxel_sizes : sequence of (dz, dy, dx)
        Voxel size of each level in `unit`, full resolution first.
    unit : str
        synthpack's length unit (``"um"``, ``"mm"``, ...); ``"px"`` writes axes without a unit.
    translations : sequence of (tz, ty, tx), optional
        Position of each level's first voxel centre, in `unit` (none: all at the origin).
    method : str, optional
        How the levels were downsampled (``multiscales[0].type``, e.g. ``"mean"``).
    label_source : str, optional
        For a label image: the path of its image group relative to it (``"../../"``
        from ``labels/<name>``); adds the ``image-label`` metadata.

    Returns
    -------
    dict
        ``{"version": "0.5", "multiscales": [...]}`` (and ``"image-label"``): the
        value of the group's ``ome`` attribute.
    """
    ngff_unit = _NGFF_UNITS.get(unit)
    axes = [{"name": axis, "type": "space", **({"unit": ngff_unit} if ngff_unit else {})} for axis in AXES]
    datasets = []
    for level, size in enumerate(voxel_sizes):
        transforms: list[dict[str, Any]] = [{"type": "scale", "scale": [float(v) for v in size]}]
        if translations is not None and any(translations[level]):
            transforms.append({"type": "translation", "translation": [float(v) for v in translations[level]]})
        datasets.append({"path": str(level), "coordinateTransformations": transforms})
    multiscale: dict[str, Any] = {"name": name, "axes": axes, "datasets": datasets}
    if method is not None:
        multiscale["type"] = method
    attributes: dict[str, Any] = {"version": NGFF_VERSION, "multiscales": [multiscale]}
    if label_source is not None:
        attributes["image-label"] = {"source": {"image": label_source}}
    return attributes


def labels_attributes(names: Sequence[str]) -> dict[str, Any]:
    """The ``ome`` attributes of an image's ``labels`` group listing its label images `names`."""
    return {"version": NGFF_VERSION, "labels": list(names)}


def label_names(attributes: Mapping[str, Any]) -> list[str]:
    """The label images a ``labels`` group lists (its attributes, as stored); empty if none."""
    ome = attributes.get("ome", attributes)
    names = ome.get("labels", []) if isinstance(ome, Mapping) else []
    return [str(n) for n in names] if isinstance(names, list) else []


def full_resolution(attributes: Mapping[str, Any]) -> tuple[str, tuple[float, float, float] | None, str | None] | None:
    """Where the full-resolution level of an OME-Zarr image is, and its voxel size.

    Reads NGFF 0.5 (``ome.multiscales``) and 0.4 (``multiscales`` at the top) attributes.

    Parameters
    ----------
    attributes : mapping
        The attributes of a Zarr group.

    Returns
    -------
    tuple or None
        ``(path, voxel_size, unit)``: the path of the level-0 array in the group, its
        voxel size ``(dz, dy, dx)`` (the dataset's scale times the multiscale's global
        scale, if any) and the unit of the space axes as NGFF spells it (None when
        the axes have none, or no scale is given). None when the group is not a
        multiscales image.

    Raises
    ------
    SynthpackInputError
        If the image is not 3D.
    """
    ome = attributes.get("ome", attributes)
    multiscales = ome.get("multiscales") if isinstance(ome, Mapping) else None
    if not multiscales or not isinstance(multiscales, list):
        return None
    multiscale = multiscales[0]
    axes = multiscale.get("axes", AXES)
    if len(axes) != 3:
        names = [a.get("name") if isinstance(a, Mapping) else a for a in axes]
        raise SynthpackInputError(f"the OME-Zarr image has the axes {names}: synthpack reads 3D (z, y, x) images only")
    dataset = multiscale["datasets"][0]
    scale = _scale(dataset.get("coordinateTransformations", []))
    global_scale = _scale(multiscale.get("coordinateTransformations", []))
    if scale is not None and global_scale is not None:
        scale = tuple(a * b for a, b in zip(scale, global_scale))
    units = {a.get("unit") for a in axes if isinstance(a, Mapping)}
    unit = units.pop() if len(units) == 1 else None
    return str(dataset["path"]), scale, unit if scale is not None else None


def _scale(transforms: Sequence[Mapping[str, Any]]) -> tuple[float, float, float] | None:
    for transform in transforms:
        if transform.get("type") == "scale" and "scale" in transform:
            return tuple(float(v) for v in transform["scale"])  # type: ignore[return-value]
    return None
