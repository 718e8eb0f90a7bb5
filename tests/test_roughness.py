import numpy as np
import pytest
from skimage import measure

from synthpack.measure.roughness import contour_length, section_roughness, slice_roughness, volume_roughness


def _disc(radius, shape=(64, 64), centre=(31.7, 32.2)):
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return (yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 < radius ** 2


def test_contour_length_is_the_marching_squares_contour_length():
    rng = np.random.default_rng(0)
    binary = np.pad(rng.random((30, 30)) > 0.5, 1).astype(float)  # saddles everywhere, all half a pixel wide
    expected = sum(np.linalg.norm(np.diff(c, axis=0), axis=1).sum() for c in measure.find_contours(binary, 0.5))
    assert contour_length(binary, 0.5) == pytest.approx(expected, rel=1e-12)
    smooth = np.pad(_disc(10.3).astype(float), 2)
    assert contour_length(smooth, 0.5) == pytest.approx(2 * np.pi * 10.3, rel=0.06)
    assert contour_length(np.zeros((5, 5)), 0.5) == 0.0


@pytest.mark.parametrize("radius", [4.0, 8.0, 15.0])
def test_a_digitised_disc_is_smooth_and_a_comb_is_rough(radius):
    disc = _disc(radius)
    assert 1.0 < section_roughness(disc) < 1.08
    comb = disc.copy()
    comb[::2] &= np.arange(64)[None, :] < 32  # every other row cut short on the right half: teeth one pixel wide
    assert section_roughness(comb) > 1.5


@pytest.mark.parametrize("radius", [8.0, 15.0])
def test_a_coarse_staircase_is_rough(radius):
    # the disc digitised on pixels three times as large: steps of three pixels along its outline
    staircase = np.kron(_disc(radius / 3, shape=(22, 22), centre=(10.6, 10.3)), np.ones((3, 3), dtype=bool))
    assert section_roughness(staircase) > 1.12 > section_roughness(_disc(radius)) + 0.05


def test_sections_are_measured_when_large_whole_and_in_the_region():
    labels = np.zeros((64, 64), dtype=np.int32)
    labels[_disc(8.0, centre=(20.0, 20.0))] = 1
    labels[_disc(2.5, centre=(45.0, 45.0))] = 2  # fewer than 30 pixels
    labels[_disc(6.0, centre=(3.0, 40.0))] = 3  # cut by the slice's border
    labels[_disc(8.0, centre=(44.0, 16.0))] = 5  # label 4 absent
    values = slice_roughness(labels)
    assert len(values) == 2
    np.testing.assert_allclose(values, [section_roughness(labels == 1), section_roughness(labels == 5)])
    region = np.zeros_like(labels, dtype=bool)
    region[:32] = True
    np.testing.assert_allclose(slice_roughness(labels, region), values[:1])
    volume = np.stack([labels, labels, np.zeros_like(labels)])
    assert len(volume_roughness(volume)) == 4
    assert len(volume_roughness(volume, slices=1)) == 2  # the first slice only
    assert len(volume_roughness(volume, np.zeros(volume.shape, dtype=bool))) == 0
