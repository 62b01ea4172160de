"""Each node's own error on screen (issue 28), offscreen and seeded: the node tables' "±mm 90 %", the error ellipsoids
of the node views, each pair's expected distance and a confidence's decisive digits, the expected errors of the SPECT
nodes not found yet with the advice on which error source to improve, and the registration panel's defaults (the
centroids as the start, the preop set saved when loaded)."""

import numpy as np
import pytest
from PySide6.QtGui import QColor
from test_gui_registration import TIMEOUT_MS, click_run, load_preop, moved_case

from snreg import geometry
from snreg.imu.monitor import ImuSnapshot
from snreg.nodes import NodeSet
from snreg.registration.report import DOUBT_COLOUR, MissingNode, PairRow
from snreg.session import IntraopNode, Session
from snreg.session.timeline import ReviewRegistration
from snreg.tracking.uncertainty import SOURCES
from snreg_gui.acquisition.screen import AcquisitionScreen
from snreg_gui.common.ellipses import ellipse_shadows, ellipsoid_rings
from snreg_gui.common.node_error import ERROR_CAPTION
from snreg_gui.common.node_views import NodeScene, ThreeViewPlot
from snreg_gui.registration.panel import RegistrationPanel
from snreg_gui.registration.tables import PAIR_COLUMNS, PairingTable
from snreg_gui.review.panels import NODE_COLUMNS, StoredRegistrations
from snreg_gui.review.screen import ReviewScreen

SCALE_90 = 2.5003           # sqrt of the 3-dof chi-square 90 % quantile: a 90 % ellipsoid's semi-axis per sd
ELONGATED = np.diag([1.0, 4.0, 16.0])      # sds 1, 2 and 4 mm: a 90 % radius of 10.0 mm


class LevelImu:
    def snapshot(self):
        return ImuSnapshot("streaming", "", 208.0, 0.0, (0.0, 0.0, 0.0), np.eye(3), 1, 0)


# -- the node tables ---------------------------------------------------------------------

def test_the_review_node_table_shows_each_nodes_90_percent_radius(qtbot, tmp_path):
    screen = ReviewScreen()
    qtbot.addWidget(screen)
    with Session.create(tmp_path / "s.h5", case_id="c") as session:
        session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0], cov_trocar_mm2=ELONGATED)
        session.add_intraop_node("SN2", "", [4.0, 5.0, 6.0])                    # stored without one
    with qtbot.waitSignal(screen.loaded, timeout=20_000):
        screen.load(tmp_path / "s.h5")
    column = NODE_COLUMNS.index(f"{ERROR_CAPTION} (mm)")
    assert [screen.node_table.item(r, column).text() for r in range(2)] == ["\u00b110.0", ""]
    assert "90 % error ellipsoid" in screen.node_table.horizontalHeaderItem(column).toolTip()


# -- the pairing tables ------------------------------------------------------------------------

def test_a_doubtful_confidence_never_reads_as_the_threshold_and_the_expected_distance_stands_beside_the_distance(qtbot):
    """Issue 28: a confidence of 0.9496 printed as 0.95 sat in an orange (doubtful) row beside a white 0.95."""
    table = PairingTable()
    qtbot.addWidget(table)
    rows = [PairRow("SN1", "", 0, "P1", "", 3.2, 0.9496, 4.1), PairRow("SN2", "", 1, "P2", "", 2.0, 0.95, 2.5)]
    table.show_rows(rows, [7.25, 6.0])
    confidence, expected = PAIR_COLUMNS.index("confidence"), PAIR_COLUMNS.index("expected mm")
    assert [table.item(r, confidence).text() for r in range(2)] == ["0.94", "0.95"]
    assert [table.item(r, expected).text() for r in range(2)] == ["7.2", "6.0"]
    assert expected == PAIR_COLUMNS.index("distance mm") + 1
    assert table.item(0, 0).background().color() == QColor(DOUBT_COLOUR)
    assert table.item(1, 0).background().color() != QColor(DOUBT_COLOUR)
    assert "0.9496 is below 0.95" in table.item(0, confidence).toolTip()
    review = StoredRegistrations()
    qtbot.addWidget(review)
    review.show_registrations([ReviewRegistration(1, "global", 2.0, rows)])
    review.choose(1)                                    # pairs only for the registration chosen
    assert [review.pairs.item(r, 2).text() for r in range(2)] == ["0.94", "0.95"]


# -- the ellipsoids ------------------------------------------------------------------------------

def test_the_rings_lie_on_each_nodes_90_percent_ellipsoid_and_the_shadows_outline_its_projection():
    rng = np.random.default_rng(2)
    centres = rng.uniform(-50, 50, (3, 3))
    turn = geometry.rotation_from_euler(30.0, 20.0, 10.0)
    covariances = np.array([turn @ ELONGATED @ turn.T, np.eye(3) * 9.0, np.full((3, 3), np.nan)])
    segments = ellipsoid_rings(centres, covariances)
    assert len(segments) % 2 == 0 and len(segments) == 2 * 3 * 2 * 36            # two known nodes, three rings each
    for node in range(2):
        ring = segments[node * 216:(node + 1) * 216] - centres[node]
        distance2 = np.einsum("ni,ij,nj->n", ring, np.linalg.inv(covariances[node]), ring)
        np.testing.assert_allclose(distance2, SCALE_90**2, rtol=1e-3)
    x, y = ellipse_shadows(centres, covariances, 0, 2)
    assert np.isnan(x).sum() == 2                                                  # one closed curve per known node
    first = np.isfinite(x[:37])
    half_width = (x[:37][first].max() - x[:37][first].min()) / 2
    assert half_width == pytest.approx(SCALE_90 * np.sqrt(covariances[0][0, 0]), rel=0.01)
    assert ellipsoid_rings(centres, None).shape == (0, 3) and ellipse_shadows(centres, None, 0, 1)[0].size == 0


def test_the_projections_draw_each_sets_ellipses_once_made_and_refit_around_them(qtbot):
    view = ThreeViewPlot()
    qtbot.addWidget(view)
    view.show()                 # a hidden view draws a scene only once shown
    qtbot.waitExposed(view)
    items = [dict(k) for k in view.ellipses]
    preop = NodeSet.from_xyz([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0]], prefix="P", cov=np.tile(np.eye(3) * 25.0, (2, 1, 1)))
    intraop = NodeSet.from_xyz([[1.0, 1.0, 0.0]], cov=ELONGATED[None])
    view.show_scene(NodeScene(preop, intraop, np.array([0]), np.array([False, True])))
    assert [dict(k) for k in view.ellipses] == items                               # the same items, new data
    for side, count in (("preop", 1), ("missing", 1), ("intraop", 1)):
        x, _ = view.ellipses[0][side].getData()
        assert np.isnan(x).sum() == count, side
    low, high = view.plots[0].vb.viewRange()[1]
    assert low <= 1.0 - SCALE_90 * 2.0 and high >= 1.0 + SCALE_90 * 2.0            # SN1's y extent is in view
    view.show_scene(NodeScene(NodeSet(preop.ids, preop.labels, preop.xyz), None))   # no covariances: no ellipses
    assert all(view.ellipses[0][side].getData()[0] is None or not len(view.ellipses[0][side].getData()[0])
               for side in ("preop", "missing", "intraop"))


# -- the expected errors of the SPECT nodes not found yet ----------------------------------------------

def test_the_acquisition_says_each_missing_nodes_expected_error_and_which_source_to_improve(qtbot):
    screen = AcquisitionScreen(LevelImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    screen.show()
    assert not screen.expected.isVisible()                                         # nothing to say yet
    screen.show_missing([MissingNode(3, "P4", "OBT R", np.array([10.0, 0.0, 200.0]), 6.2)])
    assert screen.missing_list.text() == "P4 OBT R: expected within 6 mm (90 %)"
    assert screen.expected.isVisible() and not screen.expected.advice.isVisible()
    for k in range(2):
        screen.add_node(IntraopNode(f"SN{k + 1}", "", 0, np.zeros(3), np.zeros(3), 0.3, 60, np.nan,
                                    cov_trocar_mm2=np.eye(3) * 40.0))
        sources = {source: np.zeros((3, 3)) for source in SOURCES}
        sources["imu_camera"], sources["residual"] = np.eye(3) * 36.0, np.eye(3) * 4.0
        screen.add_error_sources(f"SN{k + 1}", sources)
    advice = screen.expected.advice.text()
    assert advice.startswith("Mostly the IMU-camera angle (90 % of the stored nodes' error variance): redo the trocar "
                             "wizard") and screen.expected.advice.isVisible()
    screen.set_nodes([IntraopNode("SN1", "", 0, np.zeros(3), np.zeros(3), 0.3, 60, np.nan),
                      IntraopNode("SN0", "", 0, np.zeros(3), np.zeros(3), 0.3, 60, np.nan)])
    assert "the error variance of SN1 (stored since the app started)" in screen.expected.advice.text()
    screen.show_missing([])
    screen.set_nodes([])
    assert not screen.expected.isVisible()


def test_the_automatic_run_after_a_store_gives_the_missing_nodes_expected_errors(qtbot, panel, pelvic_nodes, tmp_path):
    """From the third stored node on, the panel registers again after each store and hands the hot spots not found
    yet with their 90 % bounds to the acquisition screen; with fewer than 3 nodes it says nothing."""
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    session = Session.create(tmp_path / "s.h5", case_id="c")
    panel.set_session(session)
    handed = []
    panel.missing_changed.connect(handed.append)
    for m in range(2):
        session.add_intraop_node(intraop.ids[m], intraop.labels[m], intraop.xyz[m], cov_trocar_mm2=np.eye(3))
        panel.rerun_after_store()
    assert not panel.busy and not any(handed)
    session.add_intraop_node(intraop.ids[2], intraop.labels[2], intraop.xyz[2], cov_trocar_mm2=np.eye(3))
    with qtbot.waitSignal(panel.missing_changed, check_params_cb=bool, timeout=TIMEOUT_MS) as missing:
        panel.rerun_after_store()
    found = {int(truth[m]) for m in range(3)}
    assert [t.preop_index for t in missing.args[0]] == [k for k in range(6) if k not in found]
    assert all(0.0 < t.bound_mm < 60.0 for t in missing.args[0])
    assert "weighed by its own error" in panel.summary.text()
    assert "\nUsed: " in panel.summary.text() and "not used: labels (" in panel.summary.text()   # issue 35
    assert len(session.registrations()) == 0                                       # automatic runs are not stored
    session.close()


def test_a_result_that_no_longer_answers_the_stored_nodes_names_no_node_missing(qtbot, panel, pelvic_nodes, tmp_path):
    """A node stored while the automatic run ran: its result is shown out of date, the next run's answers."""
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    session = Session.create(tmp_path / "s.h5", case_id="c")
    panel.set_session(session)
    for m in range(3):
        session.add_intraop_node(intraop.ids[m], intraop.labels[m], intraop.xyz[m])
    panel.rerun_after_store()
    session.add_intraop_node(intraop.ids[3], intraop.labels[3], intraop.xyz[3])     # while the first run runs
    panel.rerun_after_store()
    handed = []
    panel.missing_changed.connect(handed.append)
    qtbot.waitUntil(lambda: not panel.busy and panel.last_result is not None
                    and len(panel.last_result.pairing) == 4 and bool(panel.missing_nodes), timeout=TIMEOUT_MS)
    named = [{t.preop_index for t in missing} for missing in handed if missing]
    assert all(int(truth[3]) not in names for names in named)                      # never P(SN4) after SN4 stored
    session.close()


# -- the registration panel's defaults ------------------------------------------------------------------

def test_the_first_run_registers_from_the_centroids_without_any_alignment(qtbot, panel, pelvic_nodes, tmp_path):
    """Issue 28: the first registration was refused ("No pairing of the nodes fits within 60 degrees and 60 mm of
    the initial alignment") until the operator found "Centre on intraop"; the frames are unrelated, so the start is
    the centroids."""
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    far = NodeSet(intraop.ids, intraop.labels, intraop.xyz + [250.0, -180.0, 400.0], frame="trocar")
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(far)
    result = click_run(qtbot, panel)
    assert np.array_equal(result.pairing, truth) and result.rms_mm < 3.0
    np.testing.assert_allclose(geometry.apply(result.initial, preop.xyz).mean(axis=0), far.xyz.mean(axis=0))


def test_spect_nodes_are_saved_in_the_session_when_loaded(qtbot, panel, pelvic_nodes, tmp_path):
    """Issue 28: preop nodes loaded in the panel were saved only when a registration ran (snreg session info: 0
    preop)."""
    preop, _, _ = moved_case(pelvic_nodes, 20.0)
    with Session.create(tmp_path / "s.h5", case_id="c") as session:
        panel.set_session(session)
        load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
        qtbot.waitUntil(lambda: session.preop_nodes() is not None, timeout=TIMEOUT_MS)
        assert session.preop_nodes().ids == preop.ids and not panel.busy
    with Session.open(tmp_path / "s.h5") as reopened:
        assert len(reopened.preop_nodes()) == len(preop) and reopened.registrations() == []
        review = RegistrationPanel()
        qtbot.addWidget(review)
        review.set_session(reopened)                                               # read only: shown, nothing written
        qtbot.waitUntil(lambda: not review.busy, timeout=TIMEOUT_MS)
        assert review.preop_box.nodes.ids == preop.ids and review.message.text() == ""
        review.shutdown()


def test_the_node_views_scene_carries_the_stored_nodes_covariances(qtbot, panel, pelvic_nodes, tmp_path):
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    with_cov = NodeSet(intraop.ids, intraop.labels, intraop.xyz, frame="trocar",
                       cov=np.tile(ELONGATED, (len(intraop), 1, 1)))
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(with_cov)
    assert np.array_equal(panel.view.scene_shown.intraop.cov, with_cov.cov)         # before a run too
    result = click_run(qtbot, panel)
    shown = panel.view.scene_shown
    assert np.array_equal(shown.intraop.cov, with_cov.cov) and shown.pairing is result.pairing
    expected = PAIR_COLUMNS.index("expected mm")
    assert all(float(panel.pairing_table.item(r, expected).text()) > 0 for r in range(len(intraop)))
