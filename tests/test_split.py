import numpy as np
import pytest

from synthpack.errors import SynthpackInputError
from synthpack.scan.split import split_slices, central_block


@pytest.mark.parametrize("n", [2, 5, 9, 10, 11, 99, 100, 101, 128, 237])
def test_central_20_percent_is_test_and_never_shared(n):
    train, test = split_slices(n, "train"), split_slices(n, "test")
    assert len(test) == max(1, round(0.2 * n))
    assert np.intersect1d(train, test).size == 0
    np.testing.assert_array_equal(np.union1d(train, test), np.arange(n))
    assert np.all(np.diff(test) == 1)  # one contiguous block
    before, after = test[0], n - 1 - test[-1]
    assert before <= after <= before + 1  # centred; an odd remainder goes to the end


def test_documented_examples():
    assert central_block(100) == (40, 60)
    assert central_block(11) == (4, 6)
    assert central_block(10) == (4, 6)
    np.testing.assert_array_equal(split_slices(5, "all"), np.arange(5))


def test_bad_split_arguments():
    with pytest.raises(SynthpackInputError, match="split must be one of"):
        split_slices(10, "validation")
    with pytest.raises(SynthpackInputError, match="at least 2 slices"):
        split_slices(1, "train")
