"""The report's ablation: the classifiers on patches with a phase made flat say where a pack differs.

Two volumes hold balls of one kind at other places, and grains and pores of one kind (levels
1.0 and 0.2 with white noise); they differ in one phase's texture only (white noise against
noise of the same level blurred by a voxel). The tolerances are those of test_realism_judge.py: a classifier that cannot tell two sets
apart has a mean AUC within 0.1 of 0.5; one that sees the difference is far above it.
"""

import numpy as np
import pytest
from scipy import ndimage

from synthpack.realism import Specimen
from synthpack.realism.ablation import ABLATIONS, ablated_patches
from synthpack.measure.lattice import take_patches
from synthpack.realism.discriminator import classifier_test, specimen_patches

SHAPE = (48, 80, 80)
LEVELS = {"grains": 1.0, "pores": 0.2}
WINDOW = (0.0, 1.2)


def _balls(seed: int) -> np.ndarray:
    """Labels of up to 40 balls of radius 6-10 voxels at random places, none overlapping (seeded)."""
    rng = np.random.default_rng(seed)
    z, y, x = np.mgrid[:SHAPE[0], :SHAPE[1], :SHAPE[2]]
    out = np.zeros(SHAPE, dtype=np.int32)
    placed = []
    for _ in range(400):
        centre, radius = rng.uniform(0, SHAPE), rng.uniform(6, 10)
        if all(np.linalg.norm(centre - c) > radius + r + 1 for c, r in placed):
            placed.append((centre, radius))
            out[(z - centre[0]) ** 2 + (y - centre[1]) ** 2 + (x - centre[2]) ** 2 <= radius**2] = len(placed)
        if len(placed) == 40:
            break
    return out


@pytest.fixture(scope="module")
def labels() -> tuple[np.ndarray, np.ndarray]:
    """The labels of a source and of a pack: balls of one kind at other places."""
    return _balls(0), _balls(1)


def _specimen(labels: np.ndarray, seed: int, *, pore_blur: float = 0.0, grain_blur: float = 0.0) -> Specimen:
    """Grains 1.0 and pores 0.2, each phase with noise of std 0.05, white or blurred (then rescaled to 0.05)."""
    rng = np.random.default_rng(seed)
    volume = np.where(labels > 0, LEVELS["grains"], LEVELS["pores"]).astype(np.float64)
    for blur, phase in ((grain_blur, labels > 0), (pore_blur, labels == 0)):
        noise = rng.normal(size=SHAPE)
        noise = ndimage.gaussian_filter(noise, blur) if blur else noise
        volume[phase] += (noise / noise.std() * 0.05)[phase]
    return Specimen(f"seed {seed}", volume.astype(np.float32), labels, np.ones(SHAPE, dtype=bool), (1.0, 1.0, 1.0),
                    "px")


def _ablations(specimen: Specimen) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    patches, corners = specimen_patches(specimen, WINDOW)
    return patches, ablated_patches(patches, specimen.labels, corners, LEVELS, WINDOW)


def _aucs(first: Specimen, second: Specimen) -> dict[str, float]:
    (a, a_ablated), (b, b_ablated) = _ablations(first), _ablations(second)
    aucs = {"as it is": classifier_test(a, b).auc("logistic")}
    aucs.update({name: classifier_test(a_ablated[name], b_ablated[name]).auc("logistic") for name in ABLATIONS})
    return aucs


def test_labels_only_keeps_nothing_of_the_intensities_and_edges_only_only_the_boundary(labels):
    labels = labels[0]
    specimen = _specimen(labels, 0)
    patches, corners = specimen_patches(specimen, WINDOW)
    ablated = ablated_patches(patches, labels, corners, LEVELS, WINDOW)
    other = _ablations(_specimen(labels, 1, pore_blur=1.0))[1]
    np.testing.assert_array_equal(ablated["labels only"], other["labels only"])
    # edges only keeps the intensity's deviation from the labels alone on the boundary, hardly any inside a phase
    grains = labels > 0
    distance = np.maximum(ndimage.distance_transform_edt(grains), ndimage.distance_transform_edt(~grains))
    distance = take_patches(distance, corners, patches.shape[1])
    kept = np.abs(ablated["edges only"] - ablated["labels only"])
    assert kept[distance >= 4].mean() < 0.02 * kept[distance <= 1].mean()


def test_a_pack_that_differs_in_its_pores_is_found_there(labels):
    aucs = _aucs(_specimen(labels[0], 0), _specimen(labels[1], 1, pore_blur=1.0))
    assert aucs["as it is"] > 0.95 and aucs["grains flat"] > 0.95, aucs
    assert abs(aucs["labels only"] - 0.5) < 0.1, aucs
    # the matte leaves the pores' voxels on the boundary a part of their texture: far less to see, not nothing
    assert aucs["pores flat"] < 0.7, aucs


def test_a_pack_that_differs_in_its_grains_is_found_there(labels):
    aucs = _aucs(_specimen(labels[0], 0), _specimen(labels[1], 1, grain_blur=1.0))
    # a third of the volume is grain: fewer patches hold the difference than in the pores
    assert aucs["as it is"] > 0.8 and aucs["pores flat"] > 0.8, aucs
    assert abs(aucs["labels only"] - 0.5) < 0.1 and aucs["grains flat"] < 0.6, aucs
