import numpy as np
import pytest

from mvcjax import flipped_triangles
from mvcjax.advanced import difference, smoothness

SQUARE = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]], float)
FAN = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])


def test_difference_is_in_percent_of_the_diagonal():
    moved = SQUARE + [np.sqrt(2) * 0.01, 0]
    mean, worst = difference(moved, SQUARE, SQUARE)
    assert mean == pytest.approx(1.0) and worst == pytest.approx(1.0)
    assert difference(SQUARE, SQUARE, SQUARE) == (0.0, 0.0)


def test_smoothness_is_zero_only_for_affine_maps():
    affine = SQUARE @ np.array([[1.2, 0.3], [-0.1, 0.8]]) + 5.0
    assert smoothness(SQUARE, affine, FAN) < 1e-12
    kinked = SQUARE.copy()
    kinked[4] += [0.2, 0.0]  # moving the centre bends the fan along its edges
    assert smoothness(SQUARE, kinked, FAN) > 0.1


def test_flipped_triangles():
    folded = SQUARE.copy()
    folded[4] = [1.5, 0.5]  # the centre pushed past the right side
    assert flipped_triangles(SQUARE, SQUARE, FAN) == 0
    assert flipped_triangles(SQUARE, folded, FAN) == 1
    # Many poses at once: a count per pose, as one pose at a time gives.
    counts = flipped_triangles(SQUARE, np.stack([[SQUARE, folded], [folded, folded]]), FAN)
    assert counts.shape == (2, 2)
    np.testing.assert_array_equal(counts, [[0, 1], [1, 1]])
