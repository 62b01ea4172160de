"""The headless demo's navigation log and the figures over it, on a seeded registration and a pinhole camera."""

import numpy as np
import pytest

from snreg import geometry
from snreg.demo.navigation_check import figures
from snreg.demo.navigation_log import NavigationLog, hot_spot_truth
from snreg.nodes import NodeSet
from snreg.registration import register

FOCAL, SIZE = 800.0, (960, 540)
KEYS = {"frame", "t_s", "hot_spot", "shown", "confident", "predicted_trocar", "bound_mm", "truth_trocar", "left_px",
        "left_px_true_pose", "truth_left_px"}


def pinhole(points, eye):
    points = np.asarray(points, float) - np.array([4.0 * eye, 0.0, 0.0])
    return FOCAL * points[:, :2] / points[:, 2:] + np.array([480.0, 270.0])


def test_each_hot_spot_not_found_is_logged_against_the_truth_per_frame(pelvic_nodes):
    xyz, labels = pelvic_nodes
    preop = NodeSet.from_xyz(xyz, labels, prefix="P")
    truth_from_preop = geometry.transform_from_euler(15.0, 5.0, -10.0, [20.0, -10.0, 150.0])
    truth = geometry.apply(truth_from_preop, xyz) + np.random.default_rng(4).normal(0.0, 1.0, xyz.shape)
    spots = hot_spot_truth(xyz, xyz[[1, 0, 2, 3, 4, 5]], truth[[1, 0, 2, 3, 4, 5]])   # sources listed out of order
    assert spots[0][0] == 1 and np.allclose(spots[0][1], truth[0])
    log = NavigationLog(preop, spots, pinhole, pinhole, SIZE)
    camera_from_trocar = np.eye(4)
    true_pose = geometry.make_transform(np.eye(3), [1.0, 0.0, 0.0])       # the estimate 1 mm off along x
    log.frame(0, 0.0, camera_from_trocar, true_pose, None, set())
    assert log.entries == []                                              # no registration yet: nothing drawn
    stored = [0, 1, 3, 5]
    result = register(xyz, truth[stored], initial=truth_from_preop, preop_labels=labels,
                      intraop_labels=[labels[k] for k in stored], seed=0)
    log.registered(result)
    log.frame(7, 0.25, camera_from_trocar, true_pose, truth[2], {spots[k][0] for k in stored})
    assert [e["hot_spot"] for e in log.entries] == ["P3", "P5"] and all(set(e) == KEYS for e in log.entries)
    mapped = geometry.apply(result.transform, xyz)
    for entry, k in zip(log.entries, (2, 4)):
        assert entry["frame"] == 7 and entry["t_s"] == 0.25 and entry["shown"] is True
        assert entry["confident"] == bool(np.all(result.confidence >= 0.95))
        np.testing.assert_allclose(entry["predicted_trocar"], mapped[k], atol=1e-3)
        np.testing.assert_allclose(entry["truth_trocar"], truth[k], atol=1e-3)
        assert entry["bound_mm"] == pytest.approx(result.target_error_mm[k], abs=1e-3)
        np.testing.assert_allclose(entry["left_px"], pinhole(mapped[k][None], 0)[0], atol=0.01)
        np.testing.assert_allclose(entry["left_px_true_pose"], pinhole(mapped[k][None] + [1.0, 0.0, 0.0], 0)[0],
                                   atol=0.01)
        np.testing.assert_allclose(entry["truth_left_px"], pinhole(truth[k][None] + [1.0, 0.0, 0.0], 0)[0], atol=0.01)
    log.frame(8, 0.3, camera_from_trocar, true_pose, None, {spots[k][0] for k in stored + [2]})
    assert [e["hot_spot"] for e in log.entries[2:]] == ["P5"]             # P3's node stored: its entries end


def entry(frame, spot, shown, confident, predicted, bound, truth, px, px_true):
    return {"frame": frame, "t_s": frame / 30, "hot_spot": spot, "shown": shown, "confident": confident,
            "predicted_trocar": predicted, "bound_mm": bound, "truth_trocar": truth, "left_px": px,
            "left_px_true_pose": px_true, "truth_left_px": px_true}


def test_the_figures_count_approach_frames_the_last_frame_and_the_pixels():
    inside = [entry(1, "P4", True, True, [0, 0, 100], 6.0, [3, 0, 100], [10, 10], [13, 14]),
              entry(2, "P4", True, False, [0, 0, 100], 5.0, [4, 0, 100], [10, 10], None),
              entry(3, "P4", True, True, [0, 0, 100], 5.0, [4, 0, 100], None, None)]       # last: 4 mm, bound 5
    outside = [entry(1, "P2", False, True, [0, 0, 100], 2.0, [0, 3, 100], [0, 0], [0, 2]),
               entry(2, "P2", True, True, [0, 0, 100], 2.0, [0, 3, 100], [0, 0], [0, 1])]   # last: 3 mm, bound 2
    got = figures([inside, outside], image_width_px=960)
    assert got.runs == 2 and got.approach_frames == 5
    assert got.shown_confident == pytest.approx(3 / 5) and got.on_screen == pytest.approx(3 / 5)   # shown and on the left image
    assert got.within_bound_runs == 1
    assert got.median_bound_mm == pytest.approx(3.5) and got.median_error_mm == pytest.approx(3.5)
    assert got.median_pose_px == pytest.approx(2.0)                        # 5, 2 and 1 px
    assert "1 of 2 runs" in got.lines()[2]
