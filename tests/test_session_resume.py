"""Undo of a stored node and continuing a session after a restart (docs/design.md, Contracts; issue 6 "undo", "open/continue")."""

import h5py
import numpy as np
import pytest

from snreg.session import Session, SessionError
from snreg.session.journal import journal_path


def _store(session, node_id, x):
    return session.add_intraop_node(node_id, "OBT R", [x, 2.0, 3.0], xyz_camera=[x, 0.0, 100.0], spread_mm=0.3, n_frames=60)


def test_undo_removes_the_node_durably_and_frees_its_id(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="phantom-01") as s:
        for k in (1, 2, 3):
            _store(s, f"SN{k}", float(k))
        removed = s.remove_intraop_node("SN3")
        assert removed.id == "SN3" and s.intraop_nodes().ids == ["SN1", "SN2"]
        assert s.next_node_id() == "SN3"
        _store(s, "SN3", 30.0)                                   # the id is used again for the new node
        s.remove_intraop_node("SN1")
        with pytest.raises(SessionError, match="no stored node 'SN9'"):
            s.remove_intraop_node("SN9")
    with Session.open(path) as s:
        assert s.intraop_nodes().ids == ["SN2", "SN3"]
        assert s.intraop_nodes().xyz[1, 0] == 30.0
        assert s.next_node_id() == "SN1"
    with h5py.File(path) as h5:                                   # the HDF5 file itself, not only the journal
        assert [v.decode() for v in h5["nodes/intraop/id"][()]] == ["SN2", "SN3"]


def test_undo_holds_when_only_the_journal_is_readable(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="phantom-01") as s:
        _store(s, "SN1", 1.0)
        _store(s, "SN2", 2.0)
        s.remove_intraop_node("SN2")
    path.write_bytes(path.read_bytes()[:1500])                     # a kill tore the HDF5 file
    with Session.open(path) as s:
        assert s.damaged and s.intraop_nodes().ids == ["SN1"]


def test_resume_continues_the_same_file(tmp_path):
    path = tmp_path / "s.h5"
    t = np.arange(10, dtype=np.int64)
    with Session.create(path, case_id="phantom-01", stream_flush_s=0) as s:
        _store(s, "SN1", 1.0)
        s.append_frames(t, t, t)
    with Session.resume(path, stream_flush_s=0) as s:
        assert s.writable and s.case_id == "phantom-01"
        assert s.next_node_id() == "SN2"
        _store(s, "SN2", 2.0)
        s.append_frames(t + 10, t + 10, t + 10)
    with Session.open(path) as s:
        assert not s.writable
        assert s.intraop_nodes().ids == ["SN1", "SN2"]
        assert list(s.stream("frames")["index"]) == list(range(20))
        with pytest.raises(SessionError, match="opened for reading"):
            _store(s, "SN3", 3.0)


def test_resume_writes_what_only_the_journal_held(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="phantom-01") as s:
        _store(s, "SN1", 1.0)
        _store(s, "SN2", 2.0)
    with h5py.File(path, "r+") as h5:                             # as if a kill came between journal and HDF5
        for dataset in h5["nodes/intraop"].values():
            dataset.resize(1, axis=0)
    Session.resume(path).close()
    with h5py.File(path) as h5:
        assert [v.decode() for v in h5["nodes/intraop/id"][()]] == ["SN1", "SN2"]


def test_resume_refuses_a_damaged_or_missing_file(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="phantom-01") as s:
        _store(s, "SN1", 1.0)
    path.write_bytes(path.read_bytes()[:1500])
    with pytest.raises(SessionError, match="recover"):
        Session.resume(path)
    with pytest.raises(SessionError, match="no such session"):
        Session.resume(tmp_path / "none.h5")
    assert journal_path(path).exists()
