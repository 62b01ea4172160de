"""Stored anatomical landmarks in the review (issue 29): read apart from the nodes with their kind (Qt-free), listed in
the review's table marked as landmarks, given markers of their own on the timeline, never counted as nodes."""

import numpy as np
import pytest
from PySide6.QtCore import Qt

from snreg.landmarks import LANDMARK, NODE
from snreg.nodes import NodeSet
from snreg.registration import register
from snreg.session import Session
from snreg.session.timeline import load_review
from snreg_gui.review.screen import ReviewScreen

T0_NS = 7_000_000_000_000
PREOP = np.array([[0.0, 0.0, 0.0], [40.0, 5.0, 0.0], [5.0, 50.0, 10.0], [30.0, 40.0, 35.0]])
AORTA = "aortic bifurcation"
STORES = [("SN1", NODE, 1.0), (AORTA, LANDMARK, 2.5), ("SN2", NODE, 4.0), ("SN3", NODE, 5.5)]     # id, kind, s


@pytest.fixture(scope="module")
def session_path(tmp_path_factory):
    """Three nodes with a landmark stored between the first two, probe fixes throughout, one registration."""
    path = tmp_path_factory.mktemp("review_landmarks") / "s.h5"
    rng = np.random.default_rng(29)
    xyz = PREOP[:3] + rng.normal(0.0, 0.5, (3, 3))
    with Session.create(path, case_id="review-lm", stream_flush_s=0) as s:
        s.set_preop_nodes(NodeSet(["P1", "P2", "P3", "P4"], [""] * 4, PREOP, frame="LPS"))
        t = T0_NS + (np.arange(200) * 1e9 / 30).astype(np.int64)
        tip = np.column_stack([np.arange(200.0), np.zeros(200), np.full(200, 100.0)])
        s.append_probe(t, t, tip, tip + [0.0, 0.0, 30.0], np.tile([0.0, 0.0, 1.0], (200, 1)), np.full(200, 0.9))
        nodes = iter(xyz)
        for name, kind, t_s in STORES:
            point = next(nodes) if kind == NODE else np.array([10.0, 80.0, 40.0])
            s.add_intraop_node(name, "", point, xyz_camera=point + 100, n_frames=10, kind=kind,
                               time_ns=T0_NS + int(t_s * 1e9))
        s.add_registration(register(PREOP, xyz, method="global", seed=0), ["P1", "P2", "P3", "P4"],
                           ["SN1", "SN2", "SN3"])
    return path


def test_the_review_data_holds_the_landmarks_apart_with_their_kind(session_path):
    review = load_review(session_path)
    assert [n.id for n in review.nodes] == ["SN1", "SN2", "SN3"] and {n.kind for n in review.nodes} == {NODE}
    [mark] = review.landmarks
    assert (mark.id, mark.kind, mark.is_landmark) == (AORTA, LANDMARK, True)
    assert mark.t_s == pytest.approx(2.5) and mark.xyz_trocar == pytest.approx([10.0, 80.0, 40.0])
    assert [p.id for p in review.stored] == [name for name, _, _ in STORES]          # in the order stored
    assert review.registrations[0].intraop_ids == ["SN1", "SN2", "SN3"]               # never paired


@pytest.fixture
def screen(qtbot):
    widget = ReviewScreen()
    qtbot.addWidget(widget)
    widget.resize(1400, 900)
    widget.show()
    yield widget
    widget.shutdown()


def test_the_review_lists_a_stored_landmark_apart_and_marks_it_on_the_timeline(qtbot, screen, session_path):
    with qtbot.waitSignal(screen.loaded, timeout=20_000):
        screen.load(session_path)
    table = screen.node_table
    assert [table.item(r, 0).text() for r in range(table.rowCount())] == ["SN1", f"landmark: {AORTA}", "SN2", "SN3"]
    assert [table.item(r, 0).font().italic() for r in range(4)] == [False, True, False, False]
    assert all(table.item(1, c).font().italic() for c in range(table.columnCount()))
    assert "not a node" in table.item(1, 0).toolTip()
    assert "3 stored nodes, 1 landmark, 1 registration" in screen.status.text()           # not counted as a node
    timelines = screen.timelines
    assert sorted(timelines.node_markers) == ["SN1", "SN2", "SN3"] and list(timelines.landmark_markers) == [AORTA]
    lines = timelines.landmark_markers[AORTA]
    assert [line.value() for line in lines] == pytest.approx([2.5] * len(timelines.plots))
    assert lines[0].label.textItem.toPlainText() == "\u25c6 1"            # its number: whole names overlapped
    assert AORTA in lines[0].label.toolTip() and timelines.legend.isVisible()
    assert "\u25c6 1" in timelines.legend.text() and AORTA in timelines.legend.text()
    assert lines[0].pen.style() == Qt.PenStyle.DotLine and lines[0].pen != timelines.node_markers["SN1"][0].pen
    rect = table.visualItemRect(table.item(1, 0))
    qtbot.mouseClick(table.viewport(), Qt.MouseButton.LeftButton, pos=rect.center())
    assert all(cursor.value() == pytest.approx(2.5) for cursor in timelines.cursors)      # the landmark's own time
