"""Anatomical landmarks in the session (issue 29): intraop points of kind landmark beside the nodes, never counted as
nodes; journal, reopening, resuming, a kill, recovery, re-expression, info and exports; preop landmarks with the preop
nodes; a registration's landmark results kept; format-4 files read as nodes only."""

import argparse
import json
import os
import signal
import subprocess
import sys

import h5py
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration, camera_to_trocar
from snreg.cli.session import add_session_parser
from snreg.nodes import NodeSet, read_node_file
from snreg.registration import register
from snreg.session import Session, SessionError, calibration_version, read_intraop
from snreg.session.journal import journal_path, read_journal
from snreg.session.recovery import recover
from snreg.session.schema import FORMAT_VERSION, stereo_to_dict
from snreg.workflow.chain_change import reexpress
from snreg.workflow.registration_run import RunRequest, run_registration

SEED = 2930
AORTA, RIGHT, LEFT = "aortic bifurcation", "right common iliac bifurcation", "left common iliac bifurcation"


def _run(argv):
    parser = argparse.ArgumentParser(prog="snreg")
    add_session_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def _store(session, stereo, chain, rng):
    """SN1, the aortic bifurcation, SN2, as the acquisition stores them (camera tip, orientation, versions)."""
    versions = calibration_version(stereo_to_dict(stereo)), calibration_version(chain.to_dict())
    for name, kind in (("SN1", "node"), (AORTA, "landmark"), ("SN2", "node")):
        camera = rng.uniform([-30, -20, 70], [30, 20, 130])
        earth_from_imu = Rotation.from_euler("ZYX", rng.uniform(-15, 15, 3), degrees=True).as_matrix()
        session.add_intraop_node(name, "", camera_to_trocar(chain, earth_from_imu, camera), xyz_camera=camera,
                                 earth_from_imu=earth_from_imu, stereo_version=versions[0], chain_version=versions[1],
                                 spread_mm=0.4, n_frames=60, time_ns=int(rng.integers(1, 10**12)),
                                 cov_trocar_mm2=np.eye(3), kind=kind)


@pytest.fixture
def stored(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="lm-1") as session:
        session.set_calibration(stereo=thesis_calibration(), chain=ChainCalibration.manual())
        _store(session, thesis_calibration(), ChainCalibration.manual(), np.random.default_rng(SEED))
        assert session.next_node_id() == "SN3"
    return path


def test_a_stored_landmark_is_kept_apart_from_the_nodes_everywhere(stored):
    entries = [data for kind, data in read_journal(journal_path(stored)).entries if kind == "node"]
    assert [(e["id"], e["kind"]) for e in entries] == [("SN1", "node"), (AORTA, "landmark"), ("SN2", "node")]
    with h5py.File(stored) as h5:
        assert list(h5["nodes/intraop/kind"][()]) == [b"node", b"landmark", b"node"]
        assert h5["nodes/intraop/kind"].fletcher32 and h5.attrs["format_version"] == FORMAT_VERSION
    with Session.open(stored) as session:
        assert session.intraop_nodes().ids == ["SN1", "SN2"] and [r.id for r in session.intraop_records()] == \
            ["SN1", "SN2"]
        landmarks = session.intraop_landmarks()
        assert landmarks.ids == [AORTA] and landmarks.frame == "trocar" and landmarks.cov.shape == (1, 3, 3)
        [record] = session.intraop_records("landmark")
        assert record.kind == "landmark" and record.n_frames == 60 and np.isfinite(record.earth_from_imu).all()
        assert len(session.intraop_records(kind=None)) == 3
    read = read_intraop(stored)
    assert read.nodes.ids == ["SN1", "SN2"] and read.landmarks.ids == [AORTA]
    os.remove(journal_path(stored))                     # the HDF5 file alone says the same
    with Session.open(stored) as session:
        assert session.intraop_nodes().ids == ["SN1", "SN2"] and session.intraop_landmarks().ids == [AORTA]


def test_landmark_names_are_checked_and_shared_with_node_ids(stored):
    with Session.resume(stored) as session:
        with pytest.raises(SessionError, match="landmark 'aortic bifurcation' is already stored; take it back first"):
            session.add_intraop_node("Aortic Bifurcation", "", [0, 0, 0], kind="landmark")
        with pytest.raises(SessionError, match="'SN7' looks like a node id, not a landmark name"):
            session.add_intraop_node("SN7", "", [0, 0, 0], kind="landmark")
        with pytest.raises(SessionError, match="a landmark needs a name"):
            session.add_intraop_node("  ", "", [0, 0, 0], kind="landmark")
        with pytest.raises(SessionError, match="kind 'vessel' is neither"):
            session.add_intraop_node("x", "", [0, 0, 0], kind="vessel")
        assert session.remove_intraop_node(AORTA).kind == "landmark"
        assert session.intraop_landmarks().ids == [] and session.intraop_nodes().ids == ["SN1", "SN2"]
    with Session.open(stored) as session:
        assert len(session.intraop_records(kind=None)) == 2


def test_resume_recover_and_reexpression_carry_the_landmark(stored, tmp_path):
    with Session.resume(stored) as session:
        session.add_intraop_node(RIGHT, "", [1.0, 2.0, 3.0], kind="landmark")
        new_chain = ChainCalibration.manual(imu_trocar_mm=430.0, trocar_camera_mm=171.5)
        moved = reexpress(session, thesis_calibration(), new_chain)
        assert [node.id for node in moved] == ["SN1", AORTA, "SN2"]        # the hand-typed one has no orientation
        [aorta] = [node for node in moved if node.id == AORTA]
        assert aorta.kind == "landmark"
        np.testing.assert_allclose(aorta.xyz_trocar, camera_to_trocar(new_chain, aorta.earth_from_imu,
                                                                      aorta.xyz_camera), atol=1e-9)
    report = recover(stored, tmp_path / "clean.h5")
    assert report.nodes[0] == 2 and report.landmarks[0] == 2 and any("2 landmark(s)" in line for line in report.lines())
    with Session.open(tmp_path / "clean.h5") as session:
        assert session.intraop_nodes().ids == ["SN1", "SN2"] and session.intraop_landmarks().ids == [AORTA, RIGHT]


WRITER = r"""
import sys
from snreg.session import Session
names = ["aortic bifurcation", "right common iliac bifurcation", "left common iliac bifurcation",
         "right internal iliac origin", "left internal iliac origin", "top of the pubic symphysis"]
with Session.create(sys.argv[1], case_id="kill-lm") as s:
    for k in range(1, 1000):
        kind = "landmark" if k % 2 == 0 and k // 2 <= len(names) else "node"
        point = names[k // 2 - 1] if kind == "landmark" else f"SN{k}"
        s.add_intraop_node(point, "", [k, 0.0, 0.0], kind=kind)
        print(f"{kind}:{point}", flush=True)
"""


@pytest.mark.parametrize("stored_before_kill", [1, 2, 5, 9])
def test_a_kill_leaves_every_stored_landmark_a_landmark(tmp_path, stored_before_kill):
    path = tmp_path / "k.h5"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    printed = [proc.stdout.readline().strip() for _ in range(stored_before_kill)]
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate()
    with Session.open(path) as session:
        nodes, landmarks = session.intraop_nodes().ids, session.intraop_landmarks().ids
    for line in printed:
        kind, point = line.split(":", 1)
        assert point in (landmarks if kind == "landmark" else nodes)
    assert not set(nodes) & set(landmarks) and all(n.startswith("SN") for n in nodes)


def test_preop_landmarks_are_stored_with_the_preop_nodes(tmp_path):
    path = tmp_path / "p.h5"
    preop = NodeSet(["P1", "P2"], ["", ""], [[1, 2, 3], [4, 5, 6]], frame="LPS")
    marks = NodeSet([AORTA, LEFT], ["", "CT"], [[0, 85, 160], [40, 80, 95]], frame="LPS")
    with Session.create(path, case_id="lm-2") as session:
        session.set_preop_nodes(preop, marks)
        assert session.preop_landmarks().ids == [AORTA, LEFT]
    os.remove(journal_path(path))
    with Session.open(path) as session:
        back = session.preop_landmarks()
        assert back.ids == [AORTA, LEFT] and back.labels == ["", "CT"] and back.frame == "LPS"
        np.testing.assert_allclose(back.xyz, marks.xyz)
    with Session.resume(path) as session:
        session.set_preop_nodes(preop)                      # a preop set given alone: no preop landmarks
        assert len(session.preop_landmarks()) == 0 and session.preop_nodes().ids == ["P1", "P2"]


def _registered_session(tmp_path, swap=False):
    """A session with one node, three landmarks, preop nodes and landmarks: the registration run stores it."""
    rng = np.random.default_rng(SEED)
    turn = Rotation.from_euler("ZYX", [25, 5, -5], degrees=True).as_matrix()
    preop = NodeSet(["P1", "P2"], ["", ""], [[10, 20, 30], [-30, 40, 60]], frame="LPS")
    marks = NodeSet([AORTA, RIGHT, LEFT], ["", "", ""], [[0, 85, 160], [-40, 80, 95], [40, 80, 95]], frame="LPS")
    path = tmp_path / "r.h5"
    session = Session.create(path, case_id="lm-3")
    session.add_intraop_node("SN1", "", preop.xyz[0] @ turn.T + rng.normal(0, 1, 3))
    names = [RIGHT, AORTA, LEFT] if swap else marks.ids
    for name, xyz in zip(names, marks.xyz @ turn.T + rng.normal(0, 1, (3, 3))):
        session.add_intraop_node(name, "", xyz, kind="landmark")
    request = RunRequest(preop, session.intraop_nodes(), "global", False, np.eye(4), 60.0, 60.0, session,
                         marks, session.intraop_landmarks())
    return path, session, run_registration(request)


def test_the_registration_run_passes_the_landmarks_and_the_session_keeps_their_results(tmp_path):
    path, session, record = _registered_session(tmp_path)
    session.close()
    assert record.stored and list(record.result.pairing) == [0] and record.result.landmarks_suspect == []
    assert set(record.result.landmark_residual_mm) == {AORTA, RIGHT, LEFT}
    with Session.open(path) as reopened:
        [stored] = reopened.registrations()
        assert stored.result.landmark_residual_mm == pytest.approx(record.result.landmark_residual_mm)
        assert reopened.preop_landmarks().ids == [AORTA, RIGHT, LEFT]
    os.remove(journal_path(path))
    with Session.open(path) as reopened:
        assert reopened.registrations()[0].result.landmark_leave_one_out_mm.keys() == {AORTA, RIGHT, LEFT}


def test_a_swapped_landmark_is_named_suspect_in_the_stored_registration(tmp_path):
    path, session, record = _registered_session(tmp_path, swap=True)
    session.close()
    assert set(record.result.landmarks_suspect) & {AORTA, RIGHT}
    with Session.open(path) as reopened:
        assert reopened.registrations()[0].result.landmarks_suspect == record.result.landmarks_suspect


def test_info_lists_landmarks_apart_and_exports_carry_them(stored, tmp_path, capsys):
    assert _run(["session", "info", str(stored), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["intraop_nodes"] == 2 and [n["id"] for n in info["nodes"]] == ["SN1", "SN2"]
    assert info["intraop_landmarks"] == 1 and [n["id"] for n in info["landmarks"]] == [AORTA]
    assert info["preop_landmarks"] == 0 and info["landmarks"][0]["cov_trocar_mm2"] == np.eye(3).tolist()
    _run(["session", "info", str(stored)])
    assert f"landmarks: 1 stored in surgery ({AORTA}), 0 on the CT" in capsys.readouterr().out
    for fmt, name in (("csv", "n.csv"), ("slicer", "n.mrk.json")):
        _run(["session", "export", str(stored), "--format", fmt, "-o", str(tmp_path / name)])
        assert capsys.readouterr().out.startswith("wrote 2 nodes and 1 landmarks to")
        read = read_node_file(tmp_path / name)
        assert read.nodes.ids == ["SN1", "SN2"] and read.landmarks.ids == [AORTA]
    assert (tmp_path / "n.csv").read_text().splitlines()[-1].endswith(",landmark")
    assert json.loads((tmp_path / "n.mrk.json").read_text())["markups"][1]["name"] == "landmarks"


def test_a_format_4_file_reads_as_nodes_and_is_continued_as_the_current_format(stored):
    os.remove(journal_path(stored))
    with h5py.File(stored, "r+") as h5:                    # what a format-4 writer left: no kind column
        del h5["nodes/intraop/kind"]
        h5.attrs["format_version"] = 4
    with Session.open(stored) as session:
        assert session.intraop_nodes().ids == ["SN1", AORTA, "SN2"] and not session.damaged
        assert session.intraop_landmarks().ids == []
    with Session.resume(stored) as session:
        session.add_intraop_node(LEFT, "", [1, 2, 3], kind="landmark")
    with h5py.File(stored) as h5:
        assert list(h5["nodes/intraop/kind"][()]) == [b"node"] * 3 + [b"landmark"]
        assert h5.attrs["format_version"] == FORMAT_VERSION


def test_registering_the_session_uses_its_landmarks(tmp_path):
    path, session, _ = _registered_session(tmp_path)
    session.close()
    preop, intraop = NodeSet(["P1", "P2"], ["", ""], [[10, 20, 30], [-30, 40, 60]]), read_intraop(path)
    with Session.open(path) as reopened:
        marks = reopened.preop_landmarks()
    result = register(preop.xyz, intraop.nodes.xyz, preop_landmarks=marks, intraop_landmarks=intraop.landmarks)
    assert list(result.pairing) == [0] and len(result.landmark_residual_mm) == 3
