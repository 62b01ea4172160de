"""The "final" mark on one stored registration (issue 14): kept in the session, one at a time, durable."""

import h5py
import numpy as np
import pytest

from snreg.nodes import NodeSet
from snreg.registration import register
from snreg.session import Session, SessionError, set_final_in_file
from snreg.session.export import session_info
from snreg.session.recovery import recover


def _session(path, pelvic_nodes, runs: int = 3) -> None:
    xyz, labels = pelvic_nodes
    with Session.create(path, case_id="final-01") as s:
        s.set_preop_nodes(NodeSet.from_xyz(xyz, labels, prefix="P", frame="LPS"))
        for k in range(4):
            s.add_intraop_node(f"SN{k + 1}", labels[k], xyz[k] + 1.0)
        for method in ("icp", "cpd", "global")[:runs]:
            s.add_registration(register(xyz, xyz[:4] + 1.0, method=method), [f"P{k + 1}" for k in range(len(xyz))],
                               ["SN1", "SN2", "SN3", "SN4"])


def _node_table(path):
    with h5py.File(path, "r") as h5:
        return {name: h5["nodes/intraop"][name][()].tolist() for name in ("id", "label", "xyz_trocar", "time_ns")}


def _finals(path) -> dict:
    with h5py.File(path, "r") as h5:
        return {int(n): bool(g.attrs.get("final", False)) for n, g in h5["registration"].items()}


def test_one_final_at_a_time_round_trips_and_unmarks(tmp_path, pelvic_nodes):
    path = tmp_path / "s.h5"
    _session(path, pelvic_nodes)
    with Session.open(path) as s:
        assert s.final_registration() is None and not any(r.final for r in s.registrations())   # none by default
    nodes_before = _node_table(path)
    with Session.resume(path) as s:
        s.set_final_registration(1)
        s.set_final_registration(2)                                   # the mark moves: one final only
        assert [r.final for r in s.registrations()] == [False, False, True]
        with pytest.raises(SessionError, match="no stored registration 7"):
            s.set_final_registration(7)
    assert _finals(path) == {0: False, 1: False, 2: True}          # the attribute, on registration/2 alone
    with Session.open(path) as s:
        assert s.final_registration() == 2 and [r.final for r in s.registrations()] == [False, False, True]
    assert session_info(path)["final_registration"] == 2
    with Session.resume(path) as s:
        s.set_final_registration(None)
    with Session.open(path) as s:
        assert s.final_registration() is None
    assert _finals(path) == {0: False, 1: False, 2: False}
    assert _node_table(path) == nodes_before                          # marking never rewrote node data


def test_a_mark_that_reached_only_the_journal_survives(tmp_path, pelvic_nodes):
    """A kill after the journal line but before the attribute: the journal says which is final."""
    path = tmp_path / "s.h5"
    _session(path, pelvic_nodes)
    with Session.resume(path) as s:
        s._journal.append("final", {"n": 1})                            # what set_final_registration writes first
    assert _finals(path)[1] is False
    with Session.open(path) as s:
        assert s.final_registration() == 1
    recovered = recover(path, tmp_path / "clean.h5").path
    assert _finals(recovered) == {0: False, 1: True, 2: False}


def test_marking_a_closed_file_from_review(tmp_path, pelvic_nodes):
    path = tmp_path / "s.h5"
    _session(path, pelvic_nodes)
    nodes_before = _node_table(path)
    set_final_in_file(path, 0)
    with Session.open(path) as s:
        assert s.final_registration() == 0
    assert _node_table(path) == nodes_before
    with pytest.raises(SessionError, match="no stored registration 5"):
        set_final_in_file(path, 5)
    set_final_in_file(path, None)
    with Session.open(path) as s:
        assert s.final_registration() is None and np.all([not r.final for r in s.registrations()])
