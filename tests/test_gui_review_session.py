"""Review shows what the session holds (issue 35 item 5): its preop nodes with their down, its registrations (pairs only
for the one chosen), the Registration tab fed from the reviewed session, and the session being recorded followed."""

import numpy as np
import pytest
from PySide6.QtCore import QSettings, Qt

from snreg import geometry
from snreg.chain import ChainCalibration
from snreg.nodes import NodeSet
from snreg.preop.gravity import PreopDown
from snreg.registration import register
from snreg.session import Session
from snreg_gui.app import MainWindow
from snreg_gui.review.panels import CHOOSE_REGISTRATION, LANDMARK_MARK
from snreg_gui.review.screen import ReviewScreen

TIMEOUT_MS = 20_000
TRUTH = geometry.transform_from_euler(20.0, -8.0, 5.0, [10.0, -4.0, 250.0])
METHODS = ("icp", "cpd", "chamfer", "global")


def demo_like_session(path, seed: int = 4):
    """A session as `snreg demo --headless` leaves one: HFS preop nodes P1-P4 (LPS, with their down and a landmark),
    a chain, 4 intraop nodes and 4 registrations (one per method). Returns (preop, intraop)."""
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.choice([-1, 1], 4) * rng.uniform(25, 60, 4), rng.uniform(15, 80, 4),
                           rng.uniform(0, 80, 4)])
    preop = NodeSet.from_xyz(xyz, ["OBT R", "OBT L", "EIA R", "EIA L"], prefix="P", frame="LPS")
    intraop = NodeSet.from_xyz(geometry.apply(TRUTH, xyz) + rng.normal(0, 1.5, xyz.shape), list(preop.labels),
                               prefix="SN", frame="trocar")
    mark = NodeSet(["aortic bifurcation"], [""], [[0.0, 40.0, 120.0]], frame="LPS")
    with Session.create(path, case_id="phantom-demo") as session:
        session.set_calibration(chain=ChainCalibration.manual())
        session.set_preop_nodes(preop, landmarks=mark, down=PreopDown("HFS"))
        for i, label, point in zip(intraop.ids, intraop.labels, intraop.xyz):
            session.add_intraop_node(i, label, point, spread_mm=0.3, n_frames=60)
        for method in METHODS:
            result = register(preop.xyz, intraop.xyz, method=method, initial=TRUTH, seed=0)
            session.add_registration(result, preop.ids, intraop.ids)
    return preop, intraop


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    path = tmp_path_factory.mktemp("review_session") / "d.h5"
    return path, *demo_like_session(path)


@pytest.fixture
def settings(tmp_path):
    return QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)


def _column(table, column):
    return [table.item(r, column).text() for r in range(table.rowCount())]


def test_review_of_a_saved_demo_session_shows_its_preop_nodes_and_registrations(qtbot, saved, settings):
    path, preop, intraop = saved
    window = MainWindow(str(path), settings=settings)          # as `snreg-gui d.h5`: opened for review
    qtbot.addWidget(window)
    review, panel = window.review, window.registration
    qtbot.waitUntil(lambda: panel.preop_box.nodes is not None and panel.last_result is not None, timeout=TIMEOUT_MS)
    assert _column(review.preop_table, 0) == preop.ids + [f"{LANDMARK_MARK}aortic bifurcation"]
    caption = review.preop_caption.text()
    assert caption.startswith("4 preop nodes and 1 landmark (LPS); down from DICOM HFS (supine, head first)")
    assert ", ".join(f"{c:.3f}" for c in PreopDown("HFS").vector) in caption
    assert _column(review.registrations.list, 1) == list(METHODS)
    # the Registration tab shows the reviewed session: its preop nodes with their down, its intraop nodes, its latest
    assert panel.preop_box.nodes.ids == preop.ids and panel.preop_box.down == PreopDown("HFS")
    assert "no preop nodes" not in panel.preop_box.status.text()
    assert panel.intraop_table.rowCount() == len(intraop) and "from session phantom-demo" in panel.intraop_source.text()
    assert "Gravity cannot give the start" not in panel.start_box.status.text()
    assert panel.summary.text().startswith("Registration") or "RMS" in panel.summary.text()
    assert panel.stored.table.rowCount() == len(METHODS)
    window.shutdown()


def test_no_pairs_until_a_registration_is_chosen(qtbot, saved):
    path, _, intraop = saved
    screen = ReviewScreen()
    qtbot.addWidget(screen)
    screen.show()
    with qtbot.waitSignal(screen.loaded, timeout=TIMEOUT_MS):
        screen.load(path)
    regs = screen.registrations
    assert regs.list.rowCount() == len(METHODS) and not regs.list.selectionModel().selectedRows()
    assert regs.pairs.rowCount() == 0 and regs.choose_hint.isVisible() and regs.choose_hint.text() == CHOOSE_REGISTRATION
    assert not regs.mark_button.isEnabled()
    rect = regs.list.visualItemRect(regs.list.item(1, 0))
    qtbot.mouseClick(regs.list.viewport(), Qt.MouseButton.LeftButton, pos=rect.center())
    assert regs.chosen == 1 and regs.pairs.rowCount() == len(intraop) and not regs.choose_hint.isVisible()
    assert _column(regs.pairs, 0)[0].startswith("SN1 -> ")
    with qtbot.waitSignal(screen.loaded, timeout=TIMEOUT_MS):     # read again: the same one stays chosen
        screen.refresh()
    assert regs.chosen == 1 and regs.pairs.rowCount() == len(intraop)


def test_review_follows_the_session_being_recorded(qtbot, tmp_path, settings):
    window = MainWindow(settings=settings)
    qtbot.addWidget(window)
    window.show()
    session = Session.create(tmp_path / "live.h5", case_id="live-01")
    window.set_session(session)                     # no rig: recording into it without acquisition
    review = window.review
    assert review.following and review.status.text() != "no session loaded"
    window.tabs.setCurrentWidget(review)            # shown: read now
    qtbot.waitUntil(lambda: review.path == str(session.path) and "being recorded" in review.status.text(),
                    timeout=TIMEOUT_MS)
    assert review.node_table.rowCount() == 0
    session.add_intraop_node("SN1", "OBT R", [1.0, 2.0, 250.0])
    window._nodes_changed()                         # as the acquisition worker's node_stored signal calls it
    qtbot.waitUntil(lambda: review.node_table.rowCount() == 1 and "being recorded" in review.status.text(),
                    timeout=TIMEOUT_MS)
    window.tabs.setCurrentWidget(window.registration)     # hidden: read again when next shown, not at each store
    session.add_intraop_node("SN2", "OBT L", [4.0, 5.0, 250.0])
    window._nodes_changed()
    assert review.node_table.rowCount() == 1
    window.tabs.setCurrentWidget(review)
    qtbot.waitUntil(lambda: review.node_table.rowCount() == 2, timeout=TIMEOUT_MS)
    assert "reviewing" not in window.windowTitle()       # the session recorded is not "reviewed"
    window.shutdown()


def test_the_preop_line_says_when_the_session_holds_no_preop_set_or_no_down(tmp_path):
    from snreg.session.timeline import load_review
    from snreg_gui.review.panels import NO_PREOP, preop_rows, preop_text

    with Session.create(tmp_path / "bare.h5", case_id="bare-01") as session:
        session.add_intraop_node("SN1", "", [0.0, 0.0, 250.0])
    review = load_review(tmp_path / "bare.h5")
    assert review.preop is None and preop_text(review) == NO_PREOP and preop_rows(review) == []
    with Session.create(tmp_path / "nodown.h5", case_id="nodown-01") as session:
        session.set_preop_nodes(NodeSet.from_xyz(np.eye(3) * 10.0, ["", "", ""], prefix="P"))
    review = load_review(tmp_path / "nodown.h5")
    assert preop_text(review) == "3 preop nodes; down: not stored (no patient position)"
    assert [row[0] for row in preop_rows(review)] == ["P1", "P2", "P3"]
