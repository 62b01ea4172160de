"""The live loop's tracking in a process of its own (issue 36): the same pairs give the same fixes, reasons and
insertions as tracking in the caller's thread, pairs begun ahead come back in their order, a killed process is
restarted (after repeated deaths: tracking here for good), said in words, while the feed and the stored nodes go on,
and closing leaves no process, no shared memory, and the insertion tracker back in this process. Rendered pairs of tests/surgery_frames.py, seeded."""

import os
import signal

import numpy as np
import pytest
from conftest import holds, parent_to_kill, poll, process_gone, shared_memory_segments
from surgery_frames import NODE_A, START_MM, slide_then_rest
from test_acquisition_insertion import WINDOW, Clock, world  # noqa: F401  (world: the sliding scene, a fixture)

from snreg.odometry import InsertionTracker
from snreg.session import Session
from snreg.tracking import StereoTracker
from snreg.workflow.acquisition import INSERTION_ENDED, Acquisition
from snreg.workflow.pair_tracking import track_pair
from snreg.workflow import supervised_tracking
from snreg.workflow.supervised_tracking import RESTARTS
from snreg.workflow.tracking_child import NICER



@pytest.fixture(scope="module")
def pairs(world):
    """Held on node A, slid 10 mm, held on node B, then two pairs with no probe (a tracking error's reason)."""
    sliding = slide_then_rest(world, rest=WINDOW, to_mm=START_MM + 10.0)
    return sliding + [world.pair(len(sliding) + k, START_MM + 10.0) for k in range(2)]


def acquisition(world, session, process):
    return Acquisition(world.calibration, world.probe, world.chain, session, fixes_per_node=WINDOW, clock=Clock(),
                       insertion=InsertionTracker(world.calibration, world.chain, probe=world.probe),
                       tracking_process=process)


def run_ahead(acq, pairs, ahead=1):
    """Begin each pair before finishing the one ``ahead`` pairs back, as the app's worker does; the outcomes."""
    outcomes = []
    for pair in pairs:
        acq.begin(pair.frame, pair.imu)
        while acq.in_flight > ahead:
            outcomes.append(acq.finish())
    while acq.in_flight:
        outcomes.append(acq.finish())
    return outcomes


def same_estimates(a, b):
    for name in a.__dataclass_fields__:                   # NaN (lost) equals NaN here
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_the_process_gives_the_fixes_reasons_and_insertions_of_tracking_here_in_frame_order(world, pairs, tmp_path,
                                                                                             created_segments):
    with Session.create(tmp_path / "here.h5", case_id="here-1", stream_flush_s=0) as session:
        inline = acquisition(world, session, False)
        assert inline.tracking_pid is None
        here = [inline.process(p.frame, p.imu) for p in pairs]
    assert not created_segments                         # tracked here: no shared memory
    with Session.create(tmp_path / "there.h5", case_id="there-1", stream_flush_s=0) as session:
        acq = acquisition(world, session, True)
        pid = acq.tracking_pid
        assert pid != os.getpid() and not process_gone(pid)
        there = run_ahead(acq, pairs, ahead=2)
        # below the app's threads: the GUI thread gets a core first (set once the child runs: it answered)
        assert os.getpriority(os.PRIO_PROCESS, pid) == min(os.getpriority(os.PRIO_PROCESS, 0) + NICER, 19)
        acq.close()
        camera = session.stream("camera")[()]
    assert [o.index for o in there] == [p.frame.index for p in pairs]
    assert here[-1].fix is None and here[-1].reason                          # the pairs without a probe: in words
    for a, b in zip(here, there):
        assert a.reason == b.reason
        assert (a.fix is None) == (b.fix is None)
        if a.fix is not None:
            for name in ("tip", "centre", "axis", "quality"):
                np.testing.assert_array_equal(getattr(a.fix, name), getattr(b.fix, name))
            np.testing.assert_array_equal(a.tip_trocar, b.tip_trocar)
        same_estimates(a.insertion.estimate, b.insertion.estimate)
        assert a.insertion.used_mm == b.insertion.used_mm and a.insertion_text == b.insertion_text
    assert all(o.insertion.estimate.tracked for o in there[:-2])
    assert len(camera) == len(pairs)
    # closed: no process, no shared memory of its own left
    assert process_gone(pid) and created_segments and not created_segments & shared_memory_segments()


def test_closing_hands_the_insertion_tracker_back_to_go_on_with(world, pairs, tmp_path):
    with Session.create(tmp_path / "kept.h5", case_id="kept-1", stream_flush_s=0) as session:
        acq = acquisition(world, session, True)
        sent = acq.insertion.tracker
        run_ahead(acq, pairs[:WINDOW + 2])
        acq.close()
        kept = acq.insertion.tracker
        assert kept is not sent and acq.tracking_pid is None
        probe, serial = StereoTracker(world.calibration, world.probe), InsertionTracker(world.calibration, world.chain,
                                                                                      probe=world.probe)
        for pair in pairs[:WINDOW + 2]:                                  # the same pairs, tracked here
            track_pair(probe, serial, pair.frame.left, pair.frame.right, pair.imu.earth_from_imu)
        following = pairs[WINDOW + 2]
        went_on, expected = (track_pair(probe, tracker, following.frame.left, following.frame.right,
                                        following.imu.earth_from_imu).estimate for tracker in (kept, serial))
        assert went_on.tracked and went_on.index == following.frame.index
        same_estimates(went_on, expected)


def test_a_pair_of_another_size_raises_its_error_where_it_is_finished_as_here(world, pairs, tmp_path):
    with Session.create(tmp_path / "size.h5", case_id="size-1", stream_flush_s=0) as session:
        acq = acquisition(world, session, True)
        small = pairs[0].frame
        acq.begin(type(small)(small.left[::2], small.right[::2], small.t_left_ns, small.t_right_ns, 0), pairs[0].imu)
        with pytest.raises(ValueError, match="calibration"):
            acq.finish()
        outcome = acq.process(pairs[1].frame, pairs[1].imu)             # the process goes on
        assert outcome.fix is not None
        acq.close()


def feed_until(world, acq, done, first_index, timeout_s=60.0):
    """Begin and finish pairs held on node A, one at a time as a feed brings them, until ``done()`` holds (polled
    between pairs, never raising) or ``timeout_s`` passes; the outcomes."""
    import time
    outcomes, deadline, index = [], time.monotonic() + timeout_s, first_index
    while not holds(done) and time.monotonic() < deadline:
        outcomes.append(acq.process(world.pair(index, START_MM, NODE_A).frame, world.pair(index, START_MM).imu))
        index += 1
    assert holds(done), "the tracking process did not come back"
    return outcomes


def test_a_killed_process_is_restarted_and_a_node_stored_after_is_where_it_is(world, pairs, tmp_path,
                                                                             created_segments):
    with Session.create(tmp_path / "killed.h5", case_id="killed-1", stream_flush_s=0) as session:
        acq = acquisition(world, session, True)
        run_ahead(acq, pairs[:WINDOW])
        first = acq.store("SN1", "")
        killed = acq.tracking_pid
        os.kill(killed, signal.SIGKILL)                 # before the pair is begun: it is never answered there
        acq.begin(pairs[WINDOW].frame, pairs[WINDOW].imu)
        assert acq.finish().fix is not None                              # the pair it had: tracked here
        assert acq.tracking_problem == ("the tracking process ended (killed by signal 9); restarted; the camera's "
                                        "insertion is no longer tracked")
        assert process_gone(killed) and acq.tracking_pid not in (None, killed)
        # the feed goes on (tracked here) while the new process starts, then every pair is tracked there again
        assert poll(lambda: acq.tracking_answering)
        outcomes = run_ahead(acq, [world.pair(40 + k, START_MM, NODE_A) for k in range(WINDOW)])
        assert acq.tracking_answering and acq.tracking_stops == 1
        assert all(o.fix is not None for o in outcomes)
        assert all(not o.insertion.estimate.tracked and o.insertion.estimate.reason == INSERTION_ENDED
                   for o in outcomes)                                    # its keyframes went with the process
        second = acq.store("SN2", "", confirmed=True)
        acq.close()
        events = session.events("tracking_process_stopped")
        nodes = [n.id for n in session.intraop_records()]
    assert nodes == [first.id, second.id] and len(events) == 1 and events[0]["restarted"] is True
    # the same node, before and after: mapped at the insertion held (the camera did not move)
    assert np.linalg.norm(second.xyz_trocar - first.xyz_trocar) < 0.3
    assert np.linalg.norm(second.xyz_trocar - NODE_A) < 1.5
    assert len(created_segments) == 2 and not created_segments & shared_memory_segments()


def test_a_pair_of_another_size_while_the_process_restarts_leaves_the_pairs_in_order(world, pairs, tmp_path):
    """Tracked here (the probe alone: no fix) or by the new process if it runs already (the insertion tracker's
    error), it never puts the outcomes after it out of step."""
    with Session.create(tmp_path / "size-again.h5", case_id="size-again-1", stream_flush_s=0) as session:
        acq = acquisition(world, session, True)
        os.kill(acq.tracking_pid, signal.SIGKILL)
        assert acq.process(pairs[0].frame, pairs[0].imu).fix is not None and acq.tracking_stops == 1
        small = pairs[1].frame
        try:
            acq.begin(type(small)(small.left[::2], small.right[::2], small.t_left_ns, small.t_right_ns, 1),
                      pairs[1].imu)
            assert acq.finish().fix is None
        except ValueError as err:
            assert "calibration" in str(err)
        assert acq.in_flight == 0
        after = run_ahead(acq, pairs[2:5])
        assert [o.index for o in after] == [p.frame.index for p in pairs[2:5]]
        assert all(o.fix is not None for o in after)
        acq.close()


def test_a_process_dying_again_and_again_ends_in_tracking_here_said_in_words(world, pairs, tmp_path,
                                                                            created_segments):
    with Session.create(tmp_path / "again.h5", case_id="again-1", stream_flush_s=0) as session:
        acq = acquisition(world, session, True)
        killed = []
        for death in range(RESTARTS + 1):           # each new process killed at once, before it tracked a pair
            killed.append(acq.tracking_pid)
            os.kill(killed[-1], signal.SIGKILL)
            outcomes = feed_until(world, acq, lambda: acq.tracking_stops == death + 1, first_index=100 * death)
            assert all(o.fix is not None for o in outcomes)              # the feed went on, tracked here
            assert acq.tracking_pid not in killed
        assert acq.tracking_pid is None and not acq.tracking_answering
        assert acq.tracking_problem.startswith(f"the tracking process ended (killed by signal 9), {RESTARTS + 1} "
                                               "times in a row; the probe is tracked in the acquisition's thread "
                                               "from now on (slower)")
        assert acq.process(pairs[0].frame, pairs[0].imu).fix is not None
        acq.close()
        events = session.events("tracking_process_stopped")
    assert [e["restarted"] for e in events] == [True] * RESTARTS + [False]
    assert all(process_gone(pid) for pid in killed)
    assert len(created_segments) == RESTARTS + 1 and not created_segments & shared_memory_segments()


def test_a_process_that_cannot_be_started_again_ends_in_tracking_here_at_once(world, pairs, tmp_path, monkeypatch,
                                                                               created_segments):
    with Session.create(tmp_path / "none.h5", case_id="none-1", stream_flush_s=0) as session:
        acq = acquisition(world, session, True)

        def cannot(*args, **kwargs):
            raise OSError(24, "Too many open files")
        monkeypatch.setattr(supervised_tracking, "TrackingProcess", cannot)
        killed = acq.tracking_pid
        os.kill(killed, signal.SIGKILL)
        assert acq.process(pairs[0].frame, pairs[0].imu).fix is not None
        assert acq.tracking_pid is None and acq.tracking_stops == 1
        assert acq.tracking_problem == ("the tracking process ended (killed by signal 9); a new one could not be "
                                        "started ([Errno 24] Too many open files); the probe is tracked in the "
                                        "acquisition's thread from now on (slower); the camera's insertion is no "
                                        "longer tracked")
        acq.close()
    assert process_gone(killed) and not created_segments & shared_memory_segments()


KILLED_PARENT = """
import os, signal, sys
from snreg.camera import thesis_calibration
from snreg.probe import default_probe_model
from snreg.workflow.tracking_process import TrackingProcess
tracking = TrackingProcess(thesis_calibration().scaled(0.25), default_probe_model(), None)
print(tracking.pid, tracking._memory.name, flush=True)
sys.stdin.readline()
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_killed_parent_leaves_neither_its_tracking_process_nor_its_shared_memory(tmp_path):
    with parent_to_kill(KILLED_PARENT, tmp_path) as parent:
        pid, memory = parent.stdout.readline().split()
        assert not process_gone(int(pid)) and memory.lstrip("/") in shared_memory_segments()
    assert poll(lambda: process_gone(int(pid)) and memory.lstrip("/") not in shared_memory_segments())
