"""Store landmark in the acquisition core (snreg.workflow.acquisition): Store SN's guard (refused in words while the
probe moves), a node's provenance, a second store of a name asked first, undo, and auto-store kept off a landmark."""

import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.scene import PhantomScene, Schedule
from snreg.probe import default_probe_model
from snreg.session import Session
from snreg.sources import StereoFrame
from snreg.workflow.acquisition import Acquisition, ImuReading, StoreError, StoreNeedsConfirmation, StoreRefused

LEVEL = ImuReading(np.eye(3))
AORTA = "aortic bifurcation"


@pytest.fixture(scope="module")
def scene():
    return PhantomScene(thesis_calibration().scaled(0.5), default_probe_model(), Schedule(rest_frames=10, move_frames=1,
                                                                                        noise_variants=2))


@pytest.fixture
def acquisition(tmp_path, scene):
    session = Session.create(tmp_path / "s.h5", case_id="lm-acq", stream_flush_s=0)
    yield Acquisition(scene.renderer.calibration, default_probe_model(), ChainCalibration.manual(), session,
                      fixes_per_node=4)
    session.close()


def fill(acquisition, scene, node, n=4):
    """``n`` pairs with the probe resting on the phantom's ``node``; the last outcome."""
    for index in range(n):
        left, right = scene.render(node * (scene.schedule.rest_frames + scene.schedule.move_frames) + index % 2)
        outcome = acquisition.process(StereoFrame(left, right, 1_000_000 * index, 1_000_000 * index + 2000, index),
                                      LEVEL)
    return outcome


def test_a_landmark_store_is_refused_in_words_while_the_probe_moves(acquisition, scene):
    fill(acquisition, scene, 0, n=1)
    outcome = fill(acquisition, scene, 1, n=3)                      # the probe moved from one place to another
    assert outcome.window_spread_mm > 2.0
    assert "probe moved" in acquisition.check_landmark(AORTA).refusal
    with pytest.raises(StoreRefused, match=r"the probe moved: the last 4 fixes spread \d+\.\d mm \(limit 2\.0 mm\); "
                                           "hold it still"):
        acquisition.store_landmark(AORTA, trigger="button")
    assert acquisition.session.intraop_records(kind=None) == []
    [event] = acquisition.session.events("store_refused")
    assert event["node_id"] == AORTA and event["landmark"] is True and event["trigger"] == "button"
    with pytest.raises(StoreRefused, match="only 0 of 4 valid fixes so far"):
        Acquisition(scene.renderer.calibration, default_probe_model(), ChainCalibration.manual(),
                    acquisition.session, fixes_per_node=4).store_landmark(AORTA)      # an empty window too


def test_a_landmark_is_stored_as_a_node_is_but_never_counted_as_one(acquisition, scene):
    fill(acquisition, scene, 1)
    mark = acquisition.store_landmark("  Aortic Bifurcation ", left_jpeg=b"\xff\xd8", trigger="F6")
    assert mark.id == AORTA and mark.kind == "landmark" and mark.label == ""
    assert mark.n_frames == 4 and mark.spread_mm < 1.0 and mark.left_jpeg == b"\xff\xd8"
    assert np.linalg.norm(mark.xyz_camera - scene.truth_tip(1)) < 1.5 and np.isfinite(mark.cov_trocar_mm2).all()
    assert mark.stereo_version and mark.chain_version and np.isfinite(mark.earth_from_imu).all()
    session = acquisition.session
    assert session.intraop_nodes().ids == [] and session.intraop_landmarks().ids == [AORTA]
    assert session.next_node_id() == "SN1"
    assert not fill(acquisition, scene, 1).auto_store_due           # resting on the landmark is no new node
    assert acquisition.check_store().near is None                   # nor does Store SN ask about a landmark
    node = acquisition.store("SN1", "")
    assert node.kind == "node" and session.intraop_nodes().ids == ["SN1"]


def test_a_second_store_of_a_name_asks_first_and_undo_takes_it_back(acquisition, scene):
    fill(acquisition, scene, 1)
    first = acquisition.store_landmark(AORTA)
    fill(acquisition, scene, 2)
    with pytest.raises(StoreNeedsConfirmation, match=r"The landmark 'aortic bifurcation' is already stored, \d+\.\d mm "
                                                     "from here. Store it here instead") as asked:
        acquisition.store_landmark(AORTA)
    assert asked.value.near == AORTA
    second = acquisition.store_landmark(AORTA, confirmed=True, trigger="button")
    [replaced] = acquisition.session.events("landmark_replaced")
    assert replaced["node_id"] == AORTA and replaced["old_xyz_trocar"] == pytest.approx(first.xyz_trocar, abs=1e-3)
    [stored] = acquisition.session.intraop_records("landmark")
    np.testing.assert_allclose(stored.xyz_trocar, second.xyz_trocar)
    assert acquisition.undo().id == AORTA
    assert acquisition.session.intraop_records(kind=None) == []
    with pytest.raises(StoreError, match="no stored node to undo"):
        acquisition.undo()


def test_a_landmark_needs_a_name(acquisition, scene):
    fill(acquisition, scene, 1)
    with pytest.raises(StoreError, match="a landmark needs a name, e.g. 'aortic bifurcation'; pick one of the preop "
                                         "landmarks or type its name"):
        acquisition.store_landmark("")
    with pytest.raises(StoreError, match="looks like a node id"):
        acquisition.store_landmark("SN4")
    assert acquisition.store_landmark("left ureter crossing").id == "left ureter crossing"     # any name
