"""The chain over time in the session (issue 27): ``streams/camera`` (appended, checked by Fletcher-32, salvaged,
verified, recovered), each node's ``trocar_camera_mm`` (HDF5, journal, re-expression, ``session info``), format-3 files
without either (read as the chain's constant), and the Slicer sequence mapping each fix at its insertion."""

import json

import h5py
import numpy as np
import pytest

from snreg.chain import ChainCalibration, camera_from_probe, trocar_from_probe
from snreg.cli import main
from snreg.session import Session, SessionError
from snreg.session.export import session_info
from snreg.session.integrity import verify
from snreg.session.journal import _line, journal_path, read_journal
from snreg.session.recovery import recover
from snreg.session.schema import CAMERA_STATES, FORMAT_VERSION, STREAM_DTYPES
from snreg.session.slicer_sequence import probe_poses

T0_NS = 7_000_000_000
STEP_NS = 33_333_333
STATES = ["lost", "tracked", "tracked", "lost", "tracked"]
INSERTIONS = [np.nan, 160.0, 165.0, np.nan, 170.0]


def append_rows(session, t0_ns=T0_NS):
    t = t0_ns + STEP_NS * np.arange(len(STATES))
    session.append_camera(t, t + 2000, INSERTIONS, STATES, [0.0, 0.9, 0.8, 0.0, 0.95], [np.nan, 0.4, 0.5, np.nan, 0.3],
                          [np.nan, 0.05, 0.06, np.nan, 0.04])
    return t


def test_the_camera_stream_is_appended_checked_and_read_back(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="cam-1", stream_flush_s=0) as session:
        t = append_rows(session)
        with pytest.raises(SessionError, match="a camera state must be one of lost, tracked, got 'maybe'"):
            session.append_camera(0, 0, 1.0, "maybe", 1.0, 0.0, 0.0)
    with h5py.File(path) as h5:
        dataset = h5["streams/camera"]
        assert dataset.fletcher32 and dataset.dtype == STREAM_DTYPES["camera"]
    with Session.open(path) as session:
        rows = session.stream("camera")
        assert not session.damaged and session.problems == []
    np.testing.assert_array_equal(rows["t_host_ns"], t)
    np.testing.assert_array_equal(rows["t_device_ns"], t + 2000)
    assert [CAMERA_STATES[code] for code in rows["state"]] == STATES
    np.testing.assert_array_equal(rows["trocar_camera_mm"], INSERTIONS)           # NaN where lost, never a number
    np.testing.assert_allclose(rows["quality"], [0.0, 0.9, 0.8, 0.0, 0.95], atol=1e-6)


def test_a_damaged_camera_stream_is_named_and_the_rest_kept(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="cam-2", stream_flush_s=0) as session:
        for block in range(3):                                  # 3 chunks of 1024 rows
            t = T0_NS + STEP_NS * np.arange(block * 1024, (block + 1) * 1024)
            session.append_camera(t, t, np.full(1024, 160.0), "tracked", np.ones(1024), np.zeros(1024), np.zeros(1024))
    with h5py.File(path) as h5:
        chunk = h5["streams/camera"].id.get_chunk_info(1)
    with open(path, "r+b") as file:                             # one byte flipped in the second chunk
        file.seek(chunk.byte_offset + chunk.size // 2)
        byte = file.read(1)
        file.seek(chunk.byte_offset + chunk.size // 2)
        file.write(bytes([byte[0] ^ 0xFF]))
    report = verify(path, videos=False)
    assert not report.ok and [d.where for d in report.damaged] == ["/streams/camera"]
    assert "Fletcher-32" in report.damaged[0].why
    with Session.open(path) as session:
        assert len(session.stream("camera")) == 2048                 # the rows around the damaged chunk
    recovered = recover(path, tmp_path / "clean.h5")
    assert recovered.streams["camera"] == 2048 and verify(tmp_path / "clean.h5", videos=False).ok
    assert any(p.startswith("stream camera: 1024 of 3072 rows unreadable") for p in recovered.problems)


def as_format_3(path):
    """What snreg wrote before format 4: no camera stream, no insertion per node, in the file and in the journal."""
    with h5py.File(path, "r+") as h5:
        del h5["streams/camera"]
        del h5["nodes/intraop/trocar_camera_mm"]
        h5.attrs["format_version"] = 3
    journal = journal_path(path)
    entries = read_journal(journal).entries
    old = [(kind, {k: v for k, v in data.items() if k != "trocar_camera_mm"} if kind == "node" else
            {**data, "format_version": 3} if kind == "session" else data) for kind, data in entries]
    journal.write_bytes(b"".join(_line(kind, data) for kind, data in old))


@pytest.mark.slow
def test_a_format_3_file_without_the_camera_stream_reads_as_the_chains_constant(tmp_path, capsys):
    path = tmp_path / "old.h5"
    chain = ChainCalibration.manual()
    with Session.create(path, case_id="cam-3", stream_flush_s=0) as session:
        session.set_calibration(chain=chain)
        session.add_intraop_node("SN1", "OBT R", [1.0, 2.0, 3.0], xyz_camera=[1.0, 2.0, -155.0],
                                 earth_from_imu=np.eye(3))
        session.append_probe([T0_NS], [T0_NS], [[1.0, 2.0, 80.0]], [[1.0, 2.0, 110.0]], [[0.0, 0.0, 1.0]], [1.0])
    as_format_3(path)
    with Session.open(path) as session:
        assert not session.damaged and session.problems == [] and session.header["format_version"] == 3
        assert session.stream("camera").shape == (0,) and session.stream("camera").dtype == STREAM_DTYPES["camera"]
        [node] = session.intraop_records()
        assert np.isnan(node.trocar_camera_mm)
    assert verify(path).ok
    info = session_info(path)
    assert info["nodes"] == [{"id": "SN1", "label": "OBT R", "trocar_camera_mm": None, "cov_trocar_mm2": None}]
    assert info["streams"]["camera"] == 0 and info["camera"] == {"tracked": 0, "lost": 0} and not info["damaged"]
    poses = probe_poses(path)                                   # the constant insertion maps the fix
    np.testing.assert_allclose(poses.insertion_mm, [chain.trocar_camera_mm])
    np.testing.assert_allclose(poses.trocar_from_probe[0][:3, 3], [1.0, 2.0, 80.0 + chain.trocar_camera_mm], atol=1e-4)
    with Session.resume(path) as session:                       # continued: the file becomes the current format
        append_rows(session, T0_NS + 10**9)
        session.add_intraop_node("SN2", "", [4.0, 5.0, 6.0], trocar_camera_mm=171.5)
    with Session.open(path) as session:
        assert session.header["format_version"] == FORMAT_VERSION and not session.damaged
        assert len(session.stream("camera")) == len(STATES)
        first, second = session.intraop_records()
        assert np.isnan(first.trocar_camera_mm) and second.trocar_camera_mm == 171.5
    recovered = recover(path, tmp_path / "copy.h5")
    assert recovered.streams["camera"] == len(STATES) and not recovered.problems


def test_a_nodes_insertion_is_in_the_file_the_journal_and_session_info(tmp_path, capsys):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="cam-4") as session:
        session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0], trocar_camera_mm=171.25)
        session.add_intraop_node("SN2", "INT L", [4.0, 5.0, 6.0])
    with Session.open(path) as session:
        assert [n.trocar_camera_mm for n in session.intraop_records()][0] == 171.25
    assert main(["session", "info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["nodes"] == [{"id": "SN1", "label": "", "trocar_camera_mm": 171.25, "cov_trocar_mm2": None},
                             {"id": "SN2", "label": "INT L", "trocar_camera_mm": None, "cov_trocar_mm2": None}]
    assert main(["session", "info", str(path)]) == 0
    assert "nodes mapped at: SN1 171.2 mm, SN2 untracked" in capsys.readouterr().out
    path.unlink()                                               # the journal alone holds it too
    with Session.open(path) as session:
        first, second = session.intraop_records()
        assert first.trocar_camera_mm == 171.25 and np.isnan(second.trocar_camera_mm)


def test_a_reexpression_keeps_the_old_insertion_on_record(tmp_path):
    import dataclasses
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="cam-5") as session:
        node = session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0], trocar_camera_mm=171.25)
        session.reexpress_nodes([dataclasses.replace(node, xyz_trocar=np.array([1.0, 2.0, 5.0]),
                                                     trocar_camera_mm=173.25)], "test")
    with Session.open(path) as session:
        [node] = session.intraop_records()
        [event] = session.events("nodes_reexpressed")
    assert node.trocar_camera_mm == 173.25
    assert event["nodes"][0]["trocar_camera_mm"] == 173.25 and event["nodes"][0]["old"]["trocar_camera_mm"] == 171.25


def test_the_slicer_sequence_maps_each_fix_at_the_insertion_of_its_time(tmp_path):
    path = tmp_path / "s.h5"
    chain = ChainCalibration.manual()
    rng = np.random.default_rng(27)
    with Session.create(path, case_id="cam-6", stream_flush_s=0) as session:
        session.set_calibration(chain=chain)
        t = append_rows(session)
        times = np.r_[T0_NS - STEP_NS, t, t[-1] + STEP_NS]      # a fix before any camera row, one per pair, one after
        tips = rng.uniform([-20, -20, 70], [20, 20, 110], (len(times), 3))
        axes = np.tile([0.0, 0.6, -0.8], (len(times), 1))
        session.append_probe(times, times, tips, tips + 30 * axes, axes, np.ones(len(times)))
    start = chain.trocar_camera_mm
    expected = [start, start, 160.0, 165.0, 165.0, 170.0, 170.0]    # lost: the last tracked; before any: the start
    poses = probe_poses(path)
    np.testing.assert_allclose(poses.insertion_mm, expected)
    truth = [trocar_from_probe(chain.with_insertion(d), np.eye(3), camera_from_probe(tip, axis))
             for d, tip, axis in zip(expected, tips.astype(np.float32), axes.astype(np.float32))]
    np.testing.assert_allclose(poses.trocar_from_probe, truth, atol=1e-6)


def test_the_review_carries_the_insertion_timeline_and_each_nodes_insertion(tmp_path):
    from snreg.session.timeline import load_review

    path = tmp_path / "s.h5"
    with Session.create(path, case_id="cam-7", stream_flush_s=0) as session:
        t = append_rows(session)
        session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0], time_ns=int(t[2]), trocar_camera_mm=165.0)
    review = load_review(path)
    np.testing.assert_allclose(review.camera.t_s, (t - t[0]) / 1e9)
    np.testing.assert_array_equal(review.camera.trocar_camera_mm, INSERTIONS)
    assert list(review.camera.tracked) == [s == "tracked" for s in STATES]
    assert review.nodes[0].trocar_camera_mm == 165.0 and review.nodes[0].t_s == pytest.approx(review.camera.t_s[2])


def test_lost_stretches_say_where_the_insertion_was_held():
    """The review's lost stretches: each run of lost pairs until the next pair, at the insertion last tracked before
    it (the chain's distance before any; NaN when that is unknown)."""
    from snreg.session.timeline import CameraSeries, lost_stretches
    tracked = np.array([0, 1, 1, 0, 0, 1, 0, 0], bool)
    camera = CameraSeries(np.arange(8.0), np.where(tracked, [0, 160, 161, 0, 0, 163, 0, 0], np.nan), tracked,
                          np.zeros(8), np.zeros(8))
    np.testing.assert_array_equal(lost_stretches(camera, 158.0), [[0, 1, 158], [3, 5, 161], [6, 7, 163]])
    assert np.isnan(lost_stretches(camera, None)[0, 2]) and lost_stretches(CameraSeries.empty(), 158.0).shape == (0, 3)
