"""Session format 2 (docs/design.md, Contracts, extended): the events log, node re-expression with old values on record, and files of
format 1 still read and continued."""

from dataclasses import replace

import h5py
import numpy as np
import pytest

from snreg.session import Session, SessionError
from snreg.session.recovery import recover
from snreg.session.journal import journal_path
from snreg.session.schema import FORMAT_VERSION


def _store(session, node_id, x):
    return session.add_intraop_node(node_id, "OBT R", [x, 2.0, 3.0], xyz_camera=[x, 0.0, 100.0],
                                    earth_from_imu=np.eye(3), stereo_version="aaaaaaaa", chain_version="bbbbbbbb")


def test_events_are_durable_in_both_files_and_survive_recovery(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="ev-1") as s:
        s.log_event("store_refused", reason="the IMU is stale", trigger="F5")
        s.log_event("acquisition_started", imu="absent by choice")
        assert [e["kind"] for e in s.events()] == ["store_refused", "acquisition_started"]
    with h5py.File(path) as h5:
        assert h5["events"].shape == (2,) and h5.attrs["format_version"] == FORMAT_VERSION
    with Session.open(path) as s:
        [event] = s.events("store_refused")
        assert (event["reason"], event["trigger"], event["n"]) == ("the IMU is stale", "F5", 0)
    path.write_bytes(path.read_bytes()[:1500])                   # a kill tore the HDF5 file: the journal has them
    with Session.open(path) as s:
        assert s.damaged and len(s.events()) == 2
    recover(path)
    with Session.open(path) as s:
        assert not s.damaged and [e["n"] for e in s.events()] == [0, 1]


def test_reexpression_replaces_positions_all_at_once_and_keeps_the_old_ones(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="ev-2") as s:
        first, second = _store(s, "SN1", 1.0), _store(s, "SN2", 2.0)
        moved = [replace(first, xyz_trocar=np.array([9.0, 9.0, 9.0]), chain_version="cccccccc")]
        event = s.reexpress_nodes(moved, reason="chain changed")
        assert event["nodes"][0]["old"]["xyz_trocar"] == [1.0, 2.0, 3.0]
        with pytest.raises(SessionError, match="no stored node 'SN7' to re-express"):
            s.reexpress_nodes([replace(first, id="SN7")], reason="x")
    for reopen in (Session.open, Session.resume):
        with reopen(path) as s:
            nodes = {n.id: n for n in s.intraop_records()}
            np.testing.assert_allclose(nodes["SN1"].xyz_trocar, [9.0, 9.0, 9.0])
            assert nodes["SN1"].chain_version == "cccccccc" and nodes["SN2"].chain_version == "bbbbbbbb"
            np.testing.assert_allclose(nodes["SN2"].xyz_trocar, second.xyz_trocar)
            assert [e["kind"] for e in s.events()] == ["nodes_reexpressed"]


def _as_format_1(path):
    """What snreg wrote before format 2: no orientation or versions per node, no events, no journal kept."""
    with h5py.File(path, "r+") as h5:
        for name in ("earth_from_imu", "stereo_version", "chain_version"):
            del h5["nodes/intraop"][name]
        del h5["events"]
        h5.attrs["format_version"] = 1
    journal_path(path).unlink()


def test_a_format_1_file_reads_and_is_continued_as_format_2(tmp_path):
    path = tmp_path / "old.h5"
    with Session.create(path, case_id="ev-3") as s:
        _store(s, "SN1", 1.0)
    _as_format_1(path)
    with Session.open(path) as s:
        [node] = s.intraop_records()
        assert s.header["format_version"] == 1 and np.isnan(node.earth_from_imu).all()
        assert node.measured_under == ("", "") and s.events() == []
    with Session.resume(path) as s:
        _store(s, "SN2", 2.0)
        s.log_event("store_refused", reason="r", trigger="button")
    with Session.open(path) as s:
        first, second = s.intraop_records()
        assert s.header["format_version"] == FORMAT_VERSION and np.isnan(first.earth_from_imu).all()
        assert second.measured_under == ("aaaaaaaa", "bbbbbbbb") and len(s.events()) == 1
