"""Session API (docs/design.md, Contracts "Session (HDF5)"): round trip, streams, refusals, damaged files, privacy."""

import getpass
import hashlib
import socket

import cv2
import h5py
import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.nodes import NodeSet
from snreg.registration import register
from snreg.session import Session, SessionError, read_intraop
from snreg.session.export import session_info
from snreg.session.journal import journal_path
from snreg.session.reader import HEADER_KEYS
from snreg.session.recovery import recover


def _image(rng):
    return (rng.random((48, 64, 3)) * 255).astype(np.uint8)


def _record(path, rng, pelvic_nodes):
    """A session with calibration, preop, three nodes, a registration and streams."""
    xyz, labels = pelvic_nodes
    with Session.create(path, case_id="phantom-01") as s:
        s.set_calibration(stereo=thesis_calibration(), chain=ChainCalibration.manual())
        s.set_preop_nodes(NodeSet.from_xyz(xyz, labels, frame="LPS"))
        for k in range(3):
            s.add_intraop_node(f"SN{k + 1}", labels[k], xyz[k] + 1.0, xyz_camera=xyz[k], spread_mm=0.4 + k,
                               n_frames=30, counts=100.0 * k, left_jpeg=_image(rng), right_jpeg=_image(rng))
        s.add_registration(register(xyz, xyz[:3] + 1.0, method="cpd"), [f"SN{k + 1}" for k in range(len(xyz))],
                           ["SN1", "SN2", "SN3"])
        t = np.arange(2080, dtype=np.int64) * 4_807_692
        s.append_imu(t, t // 1000, rng.normal(size=(2080, 3)), rng.normal(size=(2080, 3)))
        s.append_probe(t[:300], t[:300], rng.normal(size=(300, 3)), rng.normal(size=(300, 3)),
                       np.tile([0.0, 0.0, 1.0], (300, 1)), np.full(300, 0.9))
        s.append_frames(t[:300], t[:300], np.arange(300))


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_round_trip(tmp_path, rng, pelvic_nodes):
    path = tmp_path / "s.h5"
    _record(path, rng, pelvic_nodes)
    xyz, labels = pelvic_nodes
    with Session.open(path) as s:
        assert not s.damaged and s.case_id == "phantom-01"
        nodes = s.intraop_nodes()
        assert nodes.ids == ["SN1", "SN2", "SN3"] and nodes.labels == labels[:3] and nodes.frame == "trocar"
        np.testing.assert_allclose(nodes.xyz, xyz[:3] + 1.0)
        np.testing.assert_allclose(nodes.counts, [0.0, 100.0, 200.0])
        record = s.intraop_records()[1]
        np.testing.assert_allclose(record.xyz_camera, xyz[1])
        assert record.n_frames == 30 and record.spread_mm == pytest.approx(1.4)
        assert cv2.imdecode(np.frombuffer(record.left_jpeg, np.uint8), cv2.IMREAD_COLOR).shape == (48, 64, 3)
        calib = s.calibration()
        np.testing.assert_allclose(calib["stereo"].K1, thesis_calibration().K1)
        np.testing.assert_allclose(calib["chain"].imu_from_camera, ChainCalibration.manual().imu_from_camera)
        assert s.preop_nodes().labels == labels
        (reg,) = s.registrations()
        assert reg.result.method == "cpd" and reg.result.transform.shape == (4, 4) and len(reg.result.pairing) == 3
        np.testing.assert_array_equal(reg.result.missing, [False] * 3 + [True] * 3)     # 3 of 6 found so far
        assert reg.result.target_error_mm.shape == (6,) and reg.result.leave_one_out_mm.shape == (3,)
        assert reg.intraop_ids == ["SN1", "SN2", "SN3"] and reg.preop_ids == [f"SN{k + 1}" for k in range(6)]
        np.testing.assert_array_equal(reg.result.initial, np.eye(4))
        imu = s.stream("imu")                         # read once, by a child process, when first asked for
        assert isinstance(imu, np.ndarray) and imu.shape == (2080,) and s.stream("imu") is imu
        assert s.stream("probe").shape == (300,) and s.stream("frames")["index"][-1] == 299
    with h5py.File(path, "r") as h5:
        assert h5["streams/imu"].chunks is not None and h5["streams/imu"].compression == "gzip"
    assert read_intraop(path).nodes.ids == ["SN1", "SN2", "SN3"]


def test_streams_are_buffered_and_flushed_in_chunks(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="c1", stream_flush_s=3600) as s:
        for k in range(10):
            s.append_imu([k], [k], [[0, 0, 1]], [[0, 0, 0]])
        assert s.stream("imu").shape == (0,)          # still in the buffer, not in the file
    with Session.open(path) as s:
        assert list(s.stream("imu")["t_host_ns"]) == list(range(10))


def test_refusals_while_writing(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="c1") as s:
        s.add_intraop_node("SN1", "", [0, 0, 0])
        with pytest.raises(SessionError, match="already stored"):
            s.add_intraop_node("SN1", "", [1, 1, 1])
        with pytest.raises(SessionError, match="3 coordinates"):
            s.add_intraop_node("SN2", "", [1, 1])
    with pytest.raises(SessionError, match="already exists"):
        Session.create(path, case_id="c1")
    with Session.open(path) as s, pytest.raises(SessionError, match="reading"):
        s.add_intraop_node("SN2", "", [0, 0, 0])


def _foreign_h5(path):
    with h5py.File(path, "w") as h5:
        h5["x"] = [1, 2, 3]


def _newer(path):
    with Session.create(path, case_id="c1"):
        pass
    journal_path(path).unlink()
    with h5py.File(path, "a") as h5:
        h5.attrs["format_version"] = 99


@pytest.mark.parametrize("make, message", [
    (lambda p: p.write_text("id,label,x,y,z\n"), "not a readable snreg session"),
    (_foreign_h5, "not a snreg session"),
    (_newer, "newer than this snreg reads"),
])
def test_unusable_files_are_refused_untouched(tmp_path, make, message):
    path = tmp_path / "s.h5"
    make(path)
    before = _digest(path)
    with pytest.raises(SessionError, match=message) as err:
        Session.open(path)
    assert str(err.value).count(". ") == 0 and "\n" not in str(err.value)
    assert _digest(path) == before
    assert not journal_path(path).exists()


def test_missing_and_truncated_without_journal(tmp_path, rng, pelvic_nodes):
    with pytest.raises(SessionError, match="no such session"):
        Session.open(tmp_path / "none.h5")
    path = tmp_path / "s.h5"
    _record(path, rng, pelvic_nodes)
    journal_path(path).unlink()
    path.write_bytes(path.read_bytes()[:2000])
    with pytest.raises(SessionError, match="recover"):
        Session.open(path)


def test_damaged_hdf5_is_read_from_the_journal_and_recovered(tmp_path, rng, pelvic_nodes):
    path = tmp_path / "s.h5"
    _record(path, rng, pelvic_nodes)
    path.write_bytes(path.read_bytes()[:2000])                         # truncated HDF5
    with open(journal_path(path), "ab") as f:                          # a torn last line
        f.write(b"0badc0de {\"kind\": \"node\", \"data\": {\"id\": \"SN9")
    with Session.open(path) as s:
        assert s.damaged and s.intraop_nodes().ids == ["SN1", "SN2", "SN3"]
        assert len(s.registrations()) == 1 and set(s.calibration()) == {"stereo", "chain"}
        assert s.stream("imu").shape == (0,)
    assert session_info(path)["journal_damaged_lines"] == 1
    out = recover(path, tmp_path / "clean.h5").path
    with Session.open(out) as s:
        assert not s.damaged and s.intraop_nodes().ids == ["SN1", "SN2", "SN3"] and s.case_id == "phantom-01"
    recover(path)                                                      # in place, the original kept aside
    assert len(list(tmp_path.glob("s.h5.damaged-*"))) == 1
    with Session.open(path) as s:
        assert not s.damaged and len(s.intraop_nodes()) == 3


@pytest.mark.parametrize("case_id", ["", "Jane Doe", "Doe,Jane", "Müller", "x" * 65, "pt-1970-01-31",
                                     "19700131", "31.01.1970", "a/b", "Smith1960", "Doe_1972",
                                     "Smith 12/03/1960", "1960-03-12"])
def test_case_ids_that_are_not_pseudonyms_are_refused(tmp_path, case_id):
    path = tmp_path / "s.h5"
    with pytest.raises(SessionError, match="case id .* is refused"):
        Session.create(path, case_id=case_id)
    assert list(tmp_path.iterdir()) == []


def test_a_session_holds_no_personal_strings(tmp_path, rng, pelvic_nodes):
    path = tmp_path / "s.h5"
    _record(path, rng, pelvic_nodes)
    with h5py.File(path, "r") as h5:
        assert set(h5.attrs) == set(HEADER_KEYS)
    for name in {getpass.getuser(), socket.gethostname(), str(tmp_path)} - {""}:
        for file in (path, journal_path(path)):
            assert name.encode() not in file.read_bytes()


def test_a_journal_is_never_started_over_another_so_two_creators_of_one_name_cannot_both_record(tmp_path):
    from snreg.session.journal import Journal, read_journal

    path = tmp_path / "s.h5.journal"
    Journal.start(path, "session", {"case_id": "first"}).close()
    with pytest.raises(SessionError, match="a journal already exists there"):
        Journal.start(path, "session", {"case_id": "second"})     # the other process lost the race for the name
    assert [data["case_id"] for _, data in read_journal(path).entries] == ["first"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5.journal"]     # no temporary file left behind
