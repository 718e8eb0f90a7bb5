"""Screenshot of a synthpack OME-Zarr pack opened in napari, with its labels layer on (docs/napari-pack.png).

Makes a pack of the built-in ``large`` sample and photographs napari's window with the
pack opened by the ``napari-ome-zarr`` reader plugin: the tomogram (a multiscale image)
and its instance labels, both placed by the voxel size of the store's metadata::

    synthpack generate --sample large --out /tmp/napari-packs --format zarr
    QT_API=pyqt6 xvfb-run -a -s "-screen 0 1400x900x24" python docs/napari_pack.py \
        /tmp/napari-packs/pack_0000/pack.zarr docs/napari-pack.png

napari is not a synthpack dependency: run this with a Python that has
``pip install "napari[pyqt6]" napari-ome-zarr`` (e.g. a throwaway virtual environment);
without a display, under Xvfb (Debian: ``apt-get install xvfb``).
"""

from __future__ import annotations

import sys

import napari
import numpy as np


def main(store: str, out: str) -> None:
    viewer = napari.Viewer(title=f"synthpack pack: {store}")
    viewer.open(store, plugin="napari-ome-zarr")
    image = next(layer for layer in viewer.layers if isinstance(layer, napari.layers.Image))
    labels = next(layer for layer in viewer.layers if isinstance(layer, napari.layers.Labels))
    coarsest = np.asarray(image.data[-1])
    image.contrast_limits = tuple(float(v) for v in np.percentile(coarsest, [1, 99.5]))
    labels.visible, labels.opacity = True, 0.45
    viewer.dims.order = (1, 0, 2)  # a side view: the slice through the tube's axis, z up the screen
    viewer.scene.camera.orientation2d = ("up", "right")
    viewer.dims.set_point(1, viewer.dims.range[1].start + (viewer.dims.range[1].stop - viewer.dims.range[1].start) / 2)
    viewer.window.resize(1300, 800)
    viewer.reset_view()
    viewer.screenshot(out, canvas_only=False)
    viewer.close()


if __name__ == "__main__":
    main(*sys.argv[1:3])
