"""Read and write CT volumes (TIFF, NPY, Zarr, NetCDF, HDF5, MetaImage, NRRD, NIfTI, raw) and 2D label images.

Volumes are NumPy arrays indexed ``(z, y, x)``. Readers return the voxel size
``(dz, dy, dx)`` and its length unit when the file records them; `read_scan`
turns a tomogram and its label volume into a validated `~synthpack.scan.core.Scan`.
`memmap_volume` memory-maps a volume file; `read_slice` reads one slice and
`read_box` one box of a memory map, a Zarr array or an array, so a slice or a
patch is read without the volume.
`write_label_image` and `read_label_image` store 2D instance label images
(PNG, TIFF, NPY), e.g. the truth and predictions of scored slices. `write_tiff`,
`write_zarr` and `write_nifti` (NIfTI-1, stored (x, y, z) as ITK and nnU-Net read it) write
volumes with their voxel size.
Writers are atomic: the data go to a temporary sibling first and are renamed
into place only once complete, so a failed write leaves nothing behind.
Their helpers, public for other writers: `atomic_file`, `atomic_directory`.

Supported inputs
----------------
- multi-page TIFF (``.tif``, ``.tiff``), voxel size from ImageJ metadata or
  the resolution tags;
- a folder of 2D TIFF slices, stacked in natural order (``slice_2.tif``
  before ``slice_10.tif``);
- NumPy ``.npy`` files;
- Zarr stores (a directory): a single array, or a group holding one array or
  arrays named ``tomogram`` / ``labels``; voxel size from the attributes
  ``voxel_size`` (z, y, x) and ``unit`` as written by `write_zarr`. An OME-Zarr
  image (NGFF 0.5 or 0.4, e.g. the ``pack.zarr`` of a Zarr pack): its
  full-resolution level, voxel size and unit from its ``multiscales`` scale and
  axes (`synthpack.io.ngff.full_resolution`); for the labels (or ``name="labels"``)
  its first label image under ``labels/``, or by `name` another image group in
  it (``"clean"``, ``"labels/instances"``);
- NetCDF files as written by the ANU CT lab's Mango tools (``.nc``), with the
  variable ``tomo`` (or ``tomo_float``) and/or ``labels``, or a folder of
  such files split along z (``block00000000.nc``, ``block00000001.nc``, ...).
  In Mango label volumes the dtype's maximum value (255 for uint8,
  2**31 - 1 for int32) marks voxels outside the round field of view; it is
  read as background (0);
- HDF5 files (``.h5``, ``.hdf5``, ``.hdf``, ``.nxs``; h5py), one dataset
  named after a colon (``scan.h5:/entry/data``) or the file's only 3D
  dataset. Voxel size from the first of these attributes found on the
  dataset or its parent groups: ``element_size_um`` (z, y, x in um, as the
  ImageJ HDF5 plugin and ilastik write it), ``voxel_size`` or ``spacing``
  (one value or z, y, x) with ``unit`` or ``units``;
- MetaImage (``.mhd``, ``.mha``; SimpleITK) and NRRD (``.nrrd``, ``.nhdr``;
  pynrrd), voxel size from their spacing, reversed from ITK's (x, y, z) to
  (z, y, x). The unit is NRRD's ``space units`` when recorded, else
  millimetres, the convention of ITK and 3D Slicer;
- NIfTI (``.nii``, ``.nii.gz``; nibabel), stored (x, y, z) and transposed
  to (z, y, x); voxel size from the header's pixdim (zooms), unit from
  ``xyzt_units`` (millimetres when it says unknown, as ITK reads it);
- raw binary (``.raw``, ``.bin``, ``.vol``) with its layout after a colon:
  ``scan.raw:ZxYxX:DTYPE:BYTE_ORDER``, e.g.
  ``scan.raw:512x1024x1024:uint16:little``: Z slices of Y rows of X voxels,
  X varying fastest, no header; the byte order (``little`` or ``big``) may
  be left out for 1-byte dtypes. It records no voxel size.

Orientation matrices (ITK direction cosines, NIfTI qform/sform) are
ignored: the array is read in the order it is stored.
HDF5, NRRD and NIfTI need the ``formats`` extra (``pip install
"synthpack[formats]"``: h5py, pynrrd, nibabel), MetaImage the ``metaimage``
extra (SimpleITK, large); without them these files give a one-line error
saying what to install.

The package holds one module per format family (`.tiff`, `.zarr_store`, `.netcdf`,
`.hdf5`, `.itk`, `.raw`, `.npy`), beside `.read` (the public readers), `._registry`
(the formats, one `~synthpack.io._registry.Format` record each: detection, the path
grammar, `SUPPORTED_FORMATS` and the command line's help come from it), `.units`,
`.lazy` and `.label_images`. This module only re-exports their public names, each
imported on first use, so that the command line reads the registry without importing
the storage libraries.
"""

from __future__ import annotations

from .._shared.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "LABEL_IMAGE_SUFFIXES": ".label_images",
    "SUPPORTED_FORMATS": "._registry",
    "atomic_directory": ".atomic",
    "atomic_file": ".atomic",
    "check_nifti_writer": ".itk",
    "convert_voxel_size": ".units",
    "create_zarr_volume": ".zarr_store",
    "memmap_volume": ".lazy",
    "read_box": ".lazy",
    "read_label_image": ".label_images",
    "read_scan": ".read",
    "read_slice": ".lazy",
    "read_tomogram": ".read",
    "read_volume": ".read",
    "write_label_image": ".label_images",
    "write_nifti": ".itk",
    "write_tiff": ".tiff",
    "write_zarr": ".zarr_store",
})
