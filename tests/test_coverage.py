"""Coverage of the image by captured checkerboard corners, view similarity and stillness (snreg.calibration.coverage)."""

import numpy as np
import pytest

from snreg.calibration.checkerboard import Board
from snreg.calibration.coverage import (SIMILAR_SHIFT_FRACTION, STILL_SHIFT_FRACTION, coverage_map, is_still,
                                        mean_corner_shift, similar_view)
from snreg.camera import thesis_calibration
from snreg.demo.board_render import random_board_poses

SIZE = (160, 90)                      # 16 x 9 cells of 10 px
DIAGONAL = float(np.hypot(*SIZE))


def projected_corners(calib, board, pose):
    """(N, 2) left-image pixels of the board's inner corners at ``pose``."""
    points = np.c_[board.object_points(), np.ones(board.n_corners)] @ pose.T
    pixels = points[:, :3] @ calib.K1.T
    return pixels[:, :2] / pixels[:, 2:]


def test_corners_are_counted_in_their_cells():
    view_a = np.array([[5.0, 5.0], [6.0, 7.0], [155.0, 85.0]])       # two in the top-left cell, one bottom-right
    view_b = np.array([[5.5, 4.0], [75.0, 45.0], [-3.0, 5.0], [20.0, 95.0]])   # the last two lie outside the image
    coverage = coverage_map([view_a, view_b], SIZE)
    expected = np.zeros((9, 16), int)
    expected[0, 0], expected[8, 15], expected[4, 7] = 3, 1, 1
    np.testing.assert_array_equal(coverage.counts, expected)
    assert coverage.fraction_covered == pytest.approx(3 / 144)
    assert coverage.image_size == SIZE


def test_grid_keeps_cells_square_and_empty_without_views():
    coverage = coverage_map([], (1920, 1080), cells_across=12)
    assert coverage.counts.shape == (7, 12)            # 12 * 1080 / 1920 = 6.75
    assert coverage.fraction_covered == 0.0


def test_coverage_grows_with_varied_board_views():
    calib, board = thesis_calibration().scaled(0.25), Board(10, 7, 10.0)
    views = [projected_corners(calib, board, pose) for pose in random_board_poses(calib, board, 8, seed=4)]
    fractions = [coverage_map(views[:n], calib.image_size).fraction_covered for n in range(len(views) + 1)]
    assert fractions[0] == 0.0
    assert all(later >= earlier for earlier, later in zip(fractions, fractions[1:]))
    assert fractions[-1] > 2 * fractions[1]
    assert coverage_map(views, calib.image_size).counts.sum() == len(views) * board.n_corners


@pytest.mark.parametrize("size, cells", [((0, 90), 16), ((160, 90), 0)])
def test_bad_grid(size, cells):
    with pytest.raises(ValueError):
        coverage_map([], size, cells_across=cells)


def test_mean_corner_shift():
    corners = np.random.default_rng(1).uniform(0, 100, (70, 2))
    assert mean_corner_shift(corners, corners + [3.0, 4.0]) == pytest.approx(5.0)
    with pytest.raises(ValueError, match="equal corner counts"):
        mean_corner_shift(corners, corners[:-1])


def test_similar_view_finds_the_nearest_close_view():
    corners = np.random.default_rng(2).uniform(0, 90, (70, 2))
    near = SIMILAR_SHIFT_FRACTION * DIAGONAL
    earlier = [corners + [0.0, 3 * near], corners + [0.5 * near, 0.0], corners + [0.2 * near, 0.0]]
    assert similar_view(corners, earlier, SIZE) == 2
    assert similar_view(corners, earlier[:1], SIZE) is None
    assert similar_view(corners, [], SIZE) is None


def test_still_board():
    corners = np.random.default_rng(3).uniform(0, 90, (70, 2))
    step = STILL_SHIFT_FRACTION * DIAGONAL
    jitter = [corners + [0.4 * step * (k % 2), 0.0] for k in range(5)]   # back and forth, under the tolerance
    assert is_still(jitter, SIZE)
    assert not is_still(jitter[:1], SIZE)                              # one frame says nothing
    assert not is_still(jitter[:2] + [None] + jitter[3:], SIZE)         # the board was lost in between
    moving = [corners + [1.5 * step * k, 0.0] for k in range(5)]
    assert not is_still(moving, SIZE)
