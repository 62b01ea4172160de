"""The codec study's bench (snreg.simulation.video_bench): how it makes a node of a rest's fixes, and which seeds it
reads. (Its measurements run for minutes: docs/guide/review.md, "Recorded video", has them and their commands.)"""

import numpy as np
import pytest

from snreg.simulation.video_bench import _seeds, main, nodes_of


def test_a_node_is_the_median_of_its_rests_fixes_and_a_fix_missing_is_left_out():
    node_of = [None, 0, 0, 0, 1, 1, None, 2]
    tips = np.array([[99, 99, 99], [1, 0, 0], [2, 0, 0], [9, 0, 0], [0, 4, 0], [np.nan] * 3, [50, 50, 50],
                     [np.nan] * 3], dtype=float)
    nodes = nodes_of(tips, node_of)
    assert nodes.shape == (4, 3)
    np.testing.assert_allclose(nodes[0], [2, 0, 0])          # the median, not the mean (4) nor the moving frame's 99
    np.testing.assert_allclose(nodes[1], [0, 4, 0])          # the fix that failed does not count
    assert np.isnan(nodes[2]).all() and np.isnan(nodes[3]).all()


def test_seeds_are_given_as_a_list_or_a_range_and_anything_else_is_refused(capsys):
    assert _seeds("3") == (3,)
    assert _seeds("0,2,5") == (0, 2, 5)
    assert _seeds("0-3,7") == (0, 1, 2, 3, 7)
    with pytest.raises(SystemExit) as exit_:
        main(["--seed", "one"])
    assert exit_.value.code == 2 and "seeds are numbers like 0, 0,2,5 or 0-5" in capsys.readouterr().err
