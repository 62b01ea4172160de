"""``snreg session retrack`` and the camera's insertion (issue 27): the insertion tracked again over the recorded video
re-maps nodes stored with a wrong one (the chain's constant after an unseen slide, or a tracker started from a wrong
distance), the old values on record; a session recorded without tracking keeps the chain's constant unless asked.
Two short recordings of a camera sliding 20 mm between two nodes (tests/surgery_frames.py)."""

import json

import numpy as np
import pytest
from conftest import start_video
from surgery_frames import NODE_A, NODE_B, START_MM, SlidingWorld, slide_then_rest

from snreg.cli import main
from snreg.odometry import InsertionTracker
from snreg.session import Session
from snreg.workflow.acquisition import Acquisition
from snreg.workflow.retrack import retrack

WINDOW = 4


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(untracked, started wrong): the same pairs recorded with video, SN1 stored on node A at the start and SN2 on
    node B after the slide; once with tracking off, once tracked from 150 mm instead of the chain's 158."""
    world = SlidingWorld()
    pairs = slide_then_rest(world, rest=WINDOW)
    folder = tmp_path_factory.mktemp("retrack")
    paths = []
    for name, tracker in (("untracked", None),
                          ("wrong", InsertionTracker(world.calibration, world.chain, start_mm=150.0,
                                                     probe=world.probe))):
        path = folder / f"{name}.h5"
        with Session.create(path, case_id=name) as session:
            session.set_calibration(stereo=world.calibration, chain=world.chain)
            start_video(session, 30.0, *world.calibration.image_size)     # every pair in the video, however loaded
            acquisition = Acquisition(world.calibration, world.probe, world.chain, session, fixes_per_node=WINDOW,
                                      video_fps=30.0, insertion=tracker, clock=lambda: pairs[-1].frame.t_left_ns)
            for k, pair in enumerate(pairs):
                acquisition.process(pair.frame, pair.imu)
                if k == WINDOW - 1:
                    acquisition.store("SN1", "")
            acquisition.store("SN2", "")
            assert session.video_state().dropped == 0
        paths.append(path)
    return paths


def node_errors(nodes):
    return [float(np.linalg.norm(xyz - truth)) for xyz, truth in zip(nodes, (NODE_A, NODE_B))]


@pytest.mark.slow
def test_retrack_follows_the_insertion_over_the_video_and_remaps_a_node_stored_at_the_constant(recorded, capsys):
    untracked, _ = recorded
    with Session.open(untracked) as session:
        before = session.intraop_records()
    assert node_errors([n.xyz_trocar for n in before])[1] > 18.0            # the slide, unseen
    kept = retrack(untracked)                                               # auto: recorded untracked, kept so
    assert kept.insertion is None and max(n.moved_mm for n in kept.nodes) < 0.5
    assert all(np.isnan(n.after_insertion_mm) for n in kept.nodes)
    followed = retrack(untracked, insertion="video")
    assert followed.insertion.to_json()["tracked"] == followed.insertion.pairs == 12
    assert [n.after_insertion_mm for n in followed.nodes] == pytest.approx([START_MM, START_MM + 20.0], abs=0.5)
    assert max(node_errors([n.after_trocar for n in followed.nodes])) < 1.5
    assert main(["session", "retrack", str(untracked), "--insertion", "video", "--dry-run", "--json"]) == 0
    dry = json.loads(capsys.readouterr().out)
    assert dry["stored"] == 0 and dry["insertion"]["tracked"] == 12
    first, second = dry["nodes"]
    assert first["before_trocar_camera_mm"] is None and second["after_trocar_camera_mm"] == pytest.approx(178.0, abs=0.5)
    with Session.open(untracked) as session:
        assert session.events("nodes_reexpressed") == []                     # a dry run stores nothing
    assert main(["session", "retrack", str(untracked), "--insertion", "video"]) == 0
    out = capsys.readouterr().out
    assert "camera insertion tracked over the video: 12 of 12 pairs" in out and "camera untracked -> 178." in out
    with Session.open(untracked) as session:
        after = session.intraop_records()
        [event] = session.events("nodes_reexpressed")
    assert [n.trocar_camera_mm for n in after] == pytest.approx([START_MM, START_MM + 20.0], abs=0.5)
    assert max(node_errors([n.xyz_trocar for n in after])) < 1.5
    old = {change["id"]: change["old"] for change in event["nodes"]}
    assert np.isnan(old["SN2"]["trocar_camera_mm"])
    np.testing.assert_allclose(old["SN2"]["xyz_trocar"], before[1].xyz_trocar)
    assert "insertion tracked over the video" in event["reason"]


@pytest.mark.slow
def test_retrack_remaps_nodes_stored_with_an_insertion_tracked_from_a_wrong_start(recorded):
    _, wrong = recorded
    with Session.open(wrong) as session:
        stored = session.intraop_records()
        assert len(session.stream("camera")) == 12
    assert [n.trocar_camera_mm for n in stored] == pytest.approx([150.0, 170.0], abs=0.5)
    assert min(node_errors([n.xyz_trocar for n in stored])) > 7.0           # 8 mm along the shaft
    result = retrack(wrong)                                                 # auto: tracked live, so again here
    assert result.insertion is not None
    assert [n.after_insertion_mm for n in result.nodes] == pytest.approx([START_MM, START_MM + 20.0], abs=0.5)
    assert max(node_errors([n.after_trocar for n in result.nodes])) < 1.5
    assert all(n.insertion_lost == 0 and n.fixes == WINDOW for n in result.nodes)
