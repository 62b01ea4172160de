"""Anatomical landmarks in the registration panel (issue 29), driven through its widgets offscreen on seeded cases:
read apart from the hot spots, counted towards the three points, given to the run, a suspect said in words, drawn."""

import numpy as np
import pytest
from PySide6.QtCore import Qt

from snreg import geometry
from snreg.nodes import NodeSet, write_nodes
from snreg.session import Session
from snreg.simulation.landmarks import LANDMARK_POSITIONS_MM
from snreg_gui.common import file_places
from snreg_gui.common.node_views import ThreeViewPlot
from snreg_gui.registration import panel as panel_module
from snreg_gui.registration.landmarks import NO_CT_LANDMARKS, landmark_lines
from snreg_gui.registration.panel import RegistrationPanel

TIMEOUT_MS = 15_000
TRUTH = geometry.transform_from_euler(25.0, -10.0, 8.0, [12.0, -6.0, 9.0])
THREE = ("aortic bifurcation", "right common iliac bifurcation", "left common iliac bifurcation")
RIGHT, LEFT = THREE[1], THREE[2]


def case(n_preop: int, n_intraop: int, seed: int = 3, sigma: float = 2.0):
    """Preop nodes P1.. and landmarks (LPS, pelvis-like); intraop nodes SN1.. (the first ``n_intraop`` preop nodes
    under TRUTH, noisy) and the landmarks touched (same names)."""
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.choice([-1, 1], n_preop) * rng.uniform(25, 60, n_preop),
                           rng.uniform(15, 80, n_preop), rng.uniform(0, 80, n_preop)])
    preop = NodeSet.from_xyz(xyz, [""] * n_preop, prefix="P")
    intraop = NodeSet.from_xyz(geometry.apply(TRUTH, xyz[:n_intraop]) + rng.normal(0, sigma, (n_intraop, 3)),
                               [""] * n_intraop, prefix="SN", frame="trocar")
    ct = np.array([LANDMARK_POSITIONS_MM[name] for name in THREE])
    marks_pre = NodeSet(list(THREE), [""] * 3, ct)
    marks_in = NodeSet(list(THREE), [""] * 3, geometry.apply(TRUTH, ct) + rng.normal(0, 1.0, (3, 3)), frame="trocar")
    return preop, intraop, marks_pre, marks_in


@pytest.fixture
def panel(qtbot, monkeypatch):
    monkeypatch.setattr(panel_module, "make_node_view", lambda parent=None: ThreeViewPlot(parent))
    widget = RegistrationPanel()
    qtbot.addWidget(widget)
    widget.show()           # the view draws a scene only while shown (a hidden one draws it when next shown)
    qtbot.waitExposed(widget)
    yield widget
    widget.shutdown()


def load(qtbot, panel, nodes, landmarks, path):
    write_nodes(nodes, path, landmarks=landmarks)
    panel.load_preop(path)
    qtbot.waitUntil(lambda: not panel.busy and panel.preop_box.nodes is not None, timeout=TIMEOUT_MS)


def click_run(qtbot, panel):
    with qtbot.waitSignal(panel.registered, timeout=TIMEOUT_MS) as blocker:
        qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    return blocker.args[0]


def test_a_preop_csv_with_a_kind_column_brings_its_landmarks_in_apart(qtbot, panel, tmp_path):
    preop, _, marks_pre, _ = case(4, 1)
    path = tmp_path / "preop.csv"
    load(qtbot, panel, preop, marks_pre, path)
    assert "kind" in path.read_text().splitlines()[0]
    box = panel.preop_box
    assert box.nodes.ids == preop.ids and box.table.rowCount() == 4          # the hot spots alone
    assert box.landmarks.ids == list(THREE)
    assert box.status.text() == "4 nodes and 3 landmarks from preop.csv"
    assert panel.landmark_table.isVisibleTo(panel) and sorted(panel.landmark_table.column("landmark")) == sorted(THREE)
    assert panel.landmark_table.column("CT") == ["yes"] * 3 and panel.landmark_table.column("surgery") == ["-"] * 3
    assert sorted(panel.view.landmark_texts(0)) == sorted(THREE)            # drawn and named on the view


def test_one_node_and_three_landmarks_register_and_are_listed_with_their_residuals(qtbot, panel, tmp_path,
                                                                                  monkeypatch):
    preop, intraop, marks_pre, marks_in = case(3, 1)
    load(qtbot, panel, preop, marks_pre, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)         # no intraop landmarks yet: 1 point of 3
    assert panel.message.text() == ("Only 1 intraop node so far; registration needs at least 3: store 2 more (or "
                                    "open a node file with more).")
    panel.set_intraop_landmarks(NodeSet(list(THREE[:1]), [""], marks_in.xyz[:1]))
    qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)         # 1 node + 1 pair: still 1 short
    assert panel.message.text().startswith("Only 1 intraop node beside 1 landmark pair so far; registration needs 3 "
                                           "points") and panel.last_result is None
    write_nodes(intraop, tmp_path / "intraop.csv", landmarks=marks_in)       # as an intraop node file with landmarks
    monkeypatch.setattr(file_places, "choose_file", lambda *_: str(tmp_path / "intraop.csv"))
    qtbot.mouseClick(panel.intraop_open_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: panel.landmark_pairs() == sorted(THREE), timeout=TIMEOUT_MS)
    result = click_run(qtbot, panel)
    assert list(result.pairing) == [0]
    assert np.abs(result.transform[:3, 3] - TRUTH[:3, 3]).max() < 8.0
    assert set(result.landmark_residual_mm) == set(THREE) and not result.landmarks_suspect
    table = panel.landmark_table
    assert table.column("surgery") == ["yes"] * 3
    assert all(0 <= float(mm) < 10 for mm in table.column("dist (mm)")) and "SUSPECT" not in panel.summary.text()
    assert sorted(text for text in panel.view.landmark_texts(0) if text) == sorted(THREE)   # each name drawn once


def test_a_swapped_landmark_name_is_said_suspect_in_words(qtbot, panel, tmp_path):
    preop, intraop, marks_pre, marks_in = case(5, 5, seed=7)
    load(qtbot, panel, preop, marks_pre, tmp_path / "preop.csv")
    swapped = NodeSet([THREE[0], LEFT, RIGHT], [""] * 3, marks_in.xyz, frame="trocar")      # right and left swapped
    panel.set_intraop_landmarks(swapped)
    panel.set_intraop_nodes(intraop)
    result = click_run(qtbot, panel)
    suspects = set(result.landmarks_suspect)
    assert suspects & {RIGHT, LEFT} and THREE[0] not in suspects
    name = sorted(suspects)[0]
    summary = panel.summary.text()
    assert f"WARNING: Landmark '{name}' contradicts the nodes and the other landmarks (" in summary
    assert "check it on the CT and in surgery" in summary
    row = panel.landmark_table.column("landmark").index(name)
    assert panel.landmark_table.column("check")[row] == "SUSPECT: left out of the fit"
    assert f"{name} (suspect)" in panel.view.landmark_texts(0)


def test_a_session_keeps_its_preop_landmarks_and_gives_its_stored_ones(qtbot, panel, tmp_path):
    """Opening a session shows (and so re-saves) its preop set: its landmarks must come with it, not be wiped."""
    preop, intraop, marks_pre, marks_in = case(3, 1)
    with Session.create(tmp_path / "s.h5", case_id="lm") as session:
        session.set_preop_nodes(preop, marks_pre)
        session.add_intraop_node("SN1", "", intraop.xyz[0])
        for name, xyz in zip(THREE, marks_in.xyz):
            session.add_intraop_node(name, "", xyz, kind="landmark")
        panel.set_session(session)
        assert panel.preop_box.landmarks.ids == list(THREE) and panel.landmark_pairs() == sorted(THREE)
        assert panel.intraop_source.text().startswith("1 node and 3 landmarks from session lm")
        assert panel.intraop_table.rowCount() == 1                           # landmarks never listed as nodes
        result = click_run(qtbot, panel)
        assert set(result.landmark_residual_mm) == set(THREE)
        qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
        assert session.preop_landmarks().ids == list(THREE)


def test_an_out_of_date_result_is_drawn_as_such(qtbot, panel, tmp_path, monkeypatch):
    """Issue 35 item 11: after Landmarks... the result is out of date; the view then draws the preop nodes under the
    initial alignment, with no pairs and a legend saying so, never the old pairs' legend over moved nodes."""
    from snreg.registration.report import mapped_preop
    from snreg_gui.common.node_scene import PREOP_MAPPED, PREOP_OUT_OF_DATE

    preop, intraop, marks_pre, _ = case(5, 5, seed=5)
    load(qtbot, panel, preop, None, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    result = click_run(qtbot, panel)
    scene = panel.view.scene_shown
    assert scene.pairing is not None and PREOP_MAPPED in panel.view.legend.text and "paired" in panel.view.legend.text
    np.testing.assert_allclose(scene.preop.xyz, mapped_preop(preop, result).xyz)        # drawn where the result maps
    write_nodes(NodeSet(list(THREE), [""] * 3, marks_pre.xyz), tmp_path / "marks.csv")
    monkeypatch.setattr(file_places, "choose_file", lambda *_: str(tmp_path / "marks.csv"))
    with qtbot.waitSignal(panel.preop_box.landmarks_changed, timeout=TIMEOUT_MS):
        qtbot.mouseClick(panel.preop_box.landmarks_button, Qt.MouseButton.LeftButton)
    assert panel.summary.text().startswith("OUT OF DATE") and not panel.pairing_table.isEnabled()
    scene, legend = panel.view.scene_shown, panel.view.legend.text
    initial = panel.alignment.transform(preop.xyz, intraop.xyz)
    np.testing.assert_allclose(scene.preop.xyz, preop.moved(initial).xyz)               # the initial alignment ...
    assert scene.pairing is None and len(scene.pair_segments()) == 0                     # ... with no pairs drawn
    assert PREOP_OUT_OF_DATE in legend and PREOP_MAPPED not in legend and "paired" not in legend
    assert not np.allclose(scene.preop.xyz, mapped_preop(preop, result).xyz)            # the case shows a difference


def test_a_stored_landmark_with_no_ct_landmarks_loaded_says_so_and_how_to_load_them():
    """Issue 35: not a typo in its name but no CT landmarks at all; with some loaded, an unknown name is checked."""
    _, _, marks_pre, marks_in = case(4, 1)
    alone = landmark_lines(None, marks_in)
    assert [line.check for line in alone] == [NO_CT_LANDMARKS] * 3
    assert "Landmarks..." in NO_CT_LANDMARKS and "check its name" not in NO_CT_LANDMARKS
    renamed = NodeSet(["elsewhere"], [""], marks_pre.xyz[:1], frame="LPS")
    checks = {line.name: line.check for line in landmark_lines(renamed, marks_in)}
    assert checks == {"elsewhere": "CT only: touch it and store it",
                      **{name: "not among the CT's landmarks: check its name" for name in THREE}}
