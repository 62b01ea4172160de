"""Acquisition with the camera's insertion tracked (issue 27): each pair mapped at its own insertion, the camera
stream, each node's insertion, and the store guard while the insertion is lost and the camera moved (refused in
words, the override on record). Rendered pairs of a camera sliding over tissue (tests/surgery_frames.py)."""

import threading

import numpy as np
import pytest
from surgery_frames import NODE_A, NODE_B, START_MM, SlidingWorld, slide_then_rest

from snreg.chain import THESIS_TROCAR_CAMERA_SD_MM, camera_to_trocar
from snreg.errors import StoreRefused
from snreg.odometry import InsertionTracker
from snreg.session import Session
from snreg.session.pose_streams import insertions_at
from snreg.workflow.acquisition import Acquisition

WINDOW = 4


class Clock:
    """Host time the test moves by hand (the store guard's fix staleness)."""

    def __init__(self):
        self.ns = 10**12

    def __call__(self):
        return self.ns


@pytest.fixture(scope="module")
def world():
    return SlidingWorld()


@pytest.fixture(scope="module")
def sliding(world):
    return slide_then_rest(world, rest=WINDOW)


def acquisition(world, session, tracked=True):
    tracker = InsertionTracker(world.calibration, world.chain, probe=world.probe) if tracked else None
    return Acquisition(world.calibration, world.probe, world.chain, session, fixes_per_node=WINDOW, clock=Clock(),
                       insertion=tracker)


def run(world, pairs, path, tracked=True):
    """Process ``pairs``, storing SN1 after the first rest and SN2 at the end; (outcomes, SN1, SN2, camera rows)."""
    with Session.create(path, case_id="slide-1", stream_flush_s=0) as session:
        acq = acquisition(world, session, tracked)
        outcomes = []
        for k, pair in enumerate(pairs):
            outcomes.append(acq.process(pair.frame, pair.imu))
            if k == WINDOW - 1:
                first = acq.store("SN1", "")
        second = acq.store("SN2", "")
        camera = session.stream("camera")[()]
    return outcomes, first, second, camera


@pytest.mark.slow
def test_each_pair_is_mapped_at_its_tracked_insertion_and_each_node_records_its_own(world, sliding, tmp_path):
    outcomes, first, second, camera = run(world, sliding, tmp_path / "tracked.h5")
    for pair, outcome in zip(sliding, outcomes):
        assert outcome.insertion.estimate.tracked and not outcome.insertion.held
        assert abs(outcome.insertion.used_mm - pair.insertion_mm) < 0.3
        assert np.linalg.norm(outcome.tip_trocar - pair.tip_trocar) < 1.5          # probe tracking's own error
        np.testing.assert_allclose(outcome.trocar_from_probe[:3, 3], outcome.tip_trocar, atol=1e-9)   # the live link's
        expected = camera_to_trocar(world.chain.with_insertion(outcome.insertion.used_mm), pair.imu.earth_from_imu,
                                    outcome.fix.tip)
        np.testing.assert_allclose(outcome.tip_trocar, expected, atol=1e-9)
    assert outcomes[-1].insertion_text == "camera 178.0 mm, +20.0 mm since calibration, tracked"
    assert first.trocar_camera_mm == pytest.approx(START_MM, abs=0.3)
    assert second.trocar_camera_mm == pytest.approx(START_MM + 20.0, abs=0.3)
    assert np.linalg.norm(first.xyz_trocar - NODE_A) < 1.5 and np.linalg.norm(second.xyz_trocar - NODE_B) < 1.5
    # one camera row per pair, on the frames' clock, as the tracker said
    assert len(camera) == len(sliding)
    np.testing.assert_array_equal(camera["t_host_ns"], [p.frame.t_left_ns for p in sliding])
    np.testing.assert_array_equal(camera["t_device_ns"], [p.frame.t_right_ns for p in sliding])
    np.testing.assert_allclose(camera["trocar_camera_mm"], [o.insertion.estimate.trocar_camera_mm for o in outcomes])
    assert set(camera["state"]) == {1} and np.all(camera["quality"] > 0.5) and np.all(camera["sd_mm"] < 0.8)
    # each row's sd is the insertion's own: the trocar calibration's at the start, with the change's since added
    assert camera["sd_mm"][0] == pytest.approx(THESIS_TROCAR_CAMERA_SD_MM) and np.all(camera["sd_mm"] >= 0.7399)
    with Session.open(tmp_path / "tracked.h5") as session:                       # on disk, HDF5 and journal
        stored = {node.id: node.trocar_camera_mm for node in session.intraop_records()}
        assert stored == {"SN1": first.trocar_camera_mm, "SN2": second.trocar_camera_mm}
        assert len(session.stream("camera")) == len(sliding)


def test_the_insertion_begun_beside_the_probe_tracker_is_the_serial_one_pair_for_pair(world, sliding, tmp_path):
    made_in = []

    class Watched(InsertionTracker):
        def prepare(self, left, right):
            made_in.append(threading.get_ident())
            return super().prepare(left, right)

    with Session.create(tmp_path / "beside.h5", case_id="beside-1", stream_flush_s=0) as session:
        acq = Acquisition(world.calibration, world.probe, world.chain, session, fixes_per_node=WINDOW, clock=Clock(),
                          insertion=Watched(world.calibration, world.chain, probe=world.probe))
        outcomes = [acq.process(pair.frame, pair.imu) for pair in sliding]
    # each pair's images were made in the insertion's own thread, beside the caller's probe tracking
    assert len(made_in) == len(sliding) and threading.get_ident() not in made_in
    serial = InsertionTracker(world.calibration, world.chain, probe=world.probe)        # one thread, in frame order
    for pair, outcome in zip(sliding, outcomes):
        expected = serial.update(pair.frame.left, pair.frame.right, pair.imu.earth_from_imu, probe_fix=outcome.fix)
        assert outcome.insertion.estimate == expected and expected.tracked
        assert outcome.insertion.estimate.index == pair.frame.index
        assert outcome.insertion.used_mm == expected.trocar_camera_mm           # the pair mapped at its own insertion


def test_without_tracking_a_node_after_a_slide_lands_displaced_by_the_slide(world, sliding, tmp_path):
    outcomes, first, second, camera = run(world, sliding, tmp_path / "still.h5", tracked=False)
    assert all(o.insertion is None and o.insertion_text == "" for o in outcomes) and len(camera) == 0
    assert np.isnan(first.trocar_camera_mm) and np.isnan(second.trocar_camera_mm)
    assert np.linalg.norm(first.xyz_trocar - NODE_A) < 1.5
    assert 18.0 < np.linalg.norm(second.xyz_trocar - NODE_B) < 22.0               # the 20 mm slide, unseen


def fill_on_node(world, acq, insertion_mm=START_MM, first_index=0):
    for k in range(first_index, first_index + WINDOW):
        outcome = acq.process(*pair_args(world.pair(k, insertion_mm, NODE_A)))
    assert outcome.insertion.estimate.tracked and outcome.store_check.refusal == ""
    return outcome


def pair_args(pair):
    return pair.frame, pair.imu


def test_a_store_while_lost_after_a_turn_is_refused_in_words_and_the_override_is_kept_on_record(world, tmp_path):
    with Session.create(tmp_path / "guard.h5", case_id="guard-1", stream_flush_s=0) as session:
        acq = acquisition(world, session)
        fill_on_node(world, acq)
        covered = world.pair(WINDOW, START_MM, covered=True, imu_turn_deg=(0.0, 3.2, 0.0))
        outcome = acq.process(*pair_args(covered))
        assert outcome.fix is None and outcome.insertion.held and outcome.valid_fixes == WINDOW
        assert outcome.insertion.used_mm == pytest.approx(START_MM, abs=0.3)       # the last tracked, held
        assert outcome.insertion_text.startswith("camera LOST (no tissue texture in view")
        check = outcome.store_check
        assert check.overridable and not outcome.auto_store_due                    # auto-store never overrides
        held_sd = outcome.insertion.sd_mm                                          # grown by the 3.2 degrees
        assert held_sd > 2.0
        assert check.refusal == ("the camera's insertion is lost (no tissue texture in view (covered, dark, smoke or "
                                 "inside the trocar)) and the camera turned 3.2 degrees since it was last tracked (the "
                                 f"insertion held is now uncertain by {held_sd:.1f} mm): show the tissue to the camera, "
                                 "or store anyway (the override is kept on record)")
        with pytest.raises(StoreRefused, match=r"turned 3\.2 degrees") as refused:
            acq.store("SN1", "OBT R", trigger="F5")
        assert refused.value.overridable and session.intraop_records() == []
        [event] = session.events("store_refused")
        assert (event["reason"], event["trigger"], event["overridable"]) == (check.refusal, "F5", True)
        node = acq.store("SN1", "OBT R", trigger="button", override=True)
        assert node.trocar_camera_mm == pytest.approx(START_MM, abs=0.3)
        [override] = session.events("store_override")
        assert (override["node_id"], override["reason"], override["trigger"]) == ("SN1", check.refusal, "button")
    with Session.open(tmp_path / "guard.h5") as session:
        assert [e["kind"] for e in session.events()] == ["store_refused", "store_override"]
        camera = session.stream("camera")
        assert list(camera["state"]) == [1] * WINDOW + [0] and np.isnan(camera["trocar_camera_mm"][-1])


def test_lost_without_moving_stores_and_lost_for_over_two_seconds_is_refused(world, tmp_path):
    with Session.create(tmp_path / "still.h5", case_id="guard-2", stream_flush_s=0) as session:
        acq = acquisition(world, session)
        fill_on_node(world, acq)
        tracked_ns = (WINDOW - 1) * 33_333_333
        outcome = acq.process(*pair_args(world.pair(WINDOW, START_MM, covered=True, imu_turn_deg=(0.5, 0.0, 0.0),
                                                   t_ns=tracked_ns + 1_500_000_000)))
        assert outcome.insertion.held and outcome.store_check.refusal == ""      # 0.5 degrees, 1.5 s: not moved
        assert acq.store("SN1", "").trocar_camera_mm == pytest.approx(START_MM, abs=0.3)     # its window's median
        outcome = acq.process(*pair_args(world.pair(WINDOW + 1, START_MM, covered=True,
                                                   t_ns=tracked_ns + 2_600_000_000)))
        assert outcome.store_check.refusal.startswith("the camera's insertion is lost (no tissue texture")
        assert "it has been lost for 2.6 s, long enough for an unseen slide (the insertion held is now uncertain by " \
            in outcome.store_check.refusal
        # the tissue back in view: tracked again, nothing to refuse
        fill_on_node(world, acq, first_index=WINDOW + 2)


def test_only_the_insertion_refusal_can_be_overridden(world, tmp_path):
    with Session.create(tmp_path / "other.h5", case_id="guard-3", stream_flush_s=0) as session:
        acq = acquisition(world, session)
        acq.process(*pair_args(world.pair(0, START_MM, NODE_A)))
        with pytest.raises(StoreRefused, match="only 1 of 4 valid fixes") as refused:
            acq.store("SN1", "", override=True)
        assert not refused.value.overridable and "overridable" not in session.events("store_refused")[0]
        assert session.events("store_override") == []


def test_the_camera_stream_gives_back_the_insertion_each_pair_was_mapped_with(world, tmp_path):
    """A lost pair is mapped at the last tracked insertion; pairs before the first tracked one at the start."""
    pairs = [world.pair(0, START_MM, covered=True), world.pair(1, START_MM, NODE_A),
             world.pair(2, START_MM + 4, NODE_A), world.pair(3, START_MM + 8, covered=True),
             world.pair(4, START_MM + 8, NODE_A)]
    with Session.create(tmp_path / "s.h5", case_id="stream-1", stream_flush_s=0) as session:
        acq = acquisition(world, session)
        used = [acq.process(*pair_args(pair)).insertion.used_mm for pair in pairs]
        camera = session.stream("camera")[()]
    assert [bool(s) for s in camera["state"]] == [False, True, True, False, True]
    assert used[0] == pytest.approx(START_MM) and used[3] == used[2] and abs(used[4] - (START_MM + 8)) < 0.3
    np.testing.assert_allclose(insertions_at(camera, [p.frame.t_left_ns for p in pairs], START_MM), used)


def test_the_live_link_sends_the_probe_and_the_nodes_as_mapped_at_each_pairs_insertion(world, sliding, tmp_path,
                                                                                         igtl_client):
    from snreg.workflow.live_link import LiveLink

    with LiveLink(0) as link, Session.create(tmp_path / "live.h5", case_id="live-1", stream_flush_s=0) as session:
        client = igtl_client(link.port)
        assert link.wait_for_client(10.0)
        acq = acquisition(world, session)
        for pair in sliding:
            outcome = acq.process(pair.frame, pair.imu)
            link.show_frame(outcome)
        link.add_node(acq.store("SN2", ""))
        tip = outcome.tip_trocar

        def arrived(c):
            poses, nodes = c.messages("ProbeTipToTrocar"), c.messages("IntraopNodes")
            return poses and nodes and np.allclose(poses[-1].matrix[:3, 3], tip, atol=1e-3) and \
                "SN2" in nodes[-1].names
        assert client.wait_for(arrived)
    assert np.linalg.norm(tip - NODE_B) < 1.5                                # after the 20 mm slide, where it is
    [position] = client.messages("IntraopNodes")[-1].positions
    assert np.linalg.norm(np.asarray(position) - NODE_B) < 1.5
