"""The registration panel driven through its real widgets (offscreen), on seeded synthetic node sets and SPECT."""

import csv
import struct

import numpy as np
import pytest
from PySide6.QtCore import Qt
from PySide6.QtGui import QGuiApplication
from PySide6.QtWidgets import QFileDialog

from snreg import geometry
from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.spect import spect_of_nodes, write_nm
from snreg.nodes import NodeSet, read_nodes, write_nodes
from snreg.registration.report import REPORT_DPI, REPORT_SIZE_IN
from snreg.registration.report_meta import read_report_metadata
from snreg.session import Session
from snreg_gui.common import node_views
from snreg_gui.common.node_views import ThreeViewPlot, make_node_view
from snreg_gui.registration.alignment import initial_transform
from snreg_gui.registration.panel import RegistrationPanel
from snreg_gui.registration.tables import PAIR_COLUMNS

TIMEOUT_MS = 15_000


def moved_case(pelvic_nodes, yaw_deg: float, seed: int = 7):
    """Preop nodes P1..P6; intraop nodes I1..I6 = preop turned by ``yaw_deg`` about their centroid, shifted 30 mm,
    1 mm noise, shuffled. Returns preop, intraop and the true pairing (preop index per intraop node)."""
    xyz, labels = pelvic_nodes
    rng = np.random.default_rng(seed)
    rotation = geometry.rotation_from_euler(yaw_deg, 0.0, 0.0)
    centre = xyz.mean(axis=0)
    truth = geometry.make_transform(rotation, centre - rotation @ centre + [30.0, 0.0, 0.0])
    order = rng.permutation(len(xyz))
    intraop_xyz = geometry.apply(truth, xyz)[order] + rng.normal(0.0, 1.0, (len(xyz), 3))
    preop = NodeSet.from_xyz(xyz, labels, prefix="P")
    intraop = NodeSet.from_xyz(intraop_xyz, [labels[k] for k in order], prefix="I", frame="trocar")
    return preop, intraop, order


def load_preop(qtbot, panel, nodes: NodeSet, path):
    write_nodes(nodes, path)
    panel.load_preop(path)
    qtbot.waitUntil(lambda: not panel.busy and panel.preop_box.nodes is not None, timeout=TIMEOUT_MS)


def three_stored(qtbot, panel, pelvic_nodes, tmp_path, case_id: str):
    """The moved case's preop nodes loaded and a session holding its first three intraop nodes given to the panel:
    (session, intraop)."""
    preop, intraop, _ = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    session = Session.create(tmp_path / "s.h5", case_id=case_id)
    for m in range(3):
        session.add_intraop_node(intraop.ids[m], intraop.labels[m], intraop.xyz[m])
    panel.set_session(session)
    return session, intraop


def click_run(qtbot, panel):
    with qtbot.waitSignal(panel.registered, timeout=TIMEOUT_MS) as blocker:
        qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    assert not panel.busy_bar.isVisible() and panel.run_button.isEnabled()
    return blocker.args[0]


def click_run_refused(qtbot, panel):
    """Run and wait for the panel to say, in words, that no pairing fits; returns what it said."""
    with qtbot.assertNotEmitted(panel.registered, wait=0):
        qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: panel.run_button.isEnabled(), timeout=TIMEOUT_MS)
    assert "no pairing" in panel.message.text().lower()
    return panel.message.text()


def table_column(table, column):
    return [table.item(row, column).text() for row in range(table.rowCount())]


@pytest.mark.parametrize("method", ["global", "icp", "cpd", "chamfer"])
def test_run_pairs_the_nodes_and_shows_them(qtbot, panel, pelvic_nodes, tmp_path, method):
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    assert not panel.preop_box.threshold_slider.isEnabled()          # a node file has no threshold
    panel.set_intraop_nodes(intraop)
    panel.method_combo.setCurrentText(method)
    result = click_run(qtbot, panel)
    assert result is panel.last_result and result.method == method
    assert np.array_equal(result.pairing, truth)
    assert result.rms_mm < 3.0
    assert table_column(panel.pairing_table, 0) == intraop.ids
    assert table_column(panel.pairing_table, 2) == [preop.ids[n] for n in truth]
    assert table_column(panel.pairing_table, 3) == intraop.labels
    assert f"RMS {result.rms_mm:.2f} mm" in panel.summary.text() and method in panel.summary.text()
    scene = panel.view.scene_shown
    assert np.allclose(scene.preop.xyz, geometry.apply(result.transform, preop.xyz))
    assert len(scene.pair_segments()) == 2 * len(intraop)


def test_three_view_draws_mapped_preop_intraop_pairs_and_labels(qtbot, pelvic_nodes, tmp_path, monkeypatch):
    monkeypatch.setattr(node_views, "opengl_available", lambda: False)
    panel = RegistrationPanel()
    qtbot.addWidget(panel)
    panel.show()                # the view draws a scene only while shown
    qtbot.waitExposed(panel)
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    result = click_run(qtbot, panel)
    view = panel.view
    assert isinstance(view, ThreeViewPlot) and view.kind == "three-view"
    moved = geometry.apply(result.transform, preop.xyz)
    for k, (h, v) in enumerate([(0, 1), (0, 2), (1, 2)]):
        x, y = view.preop_dots[k].getData()
        assert np.allclose(np.c_[x, y], moved[:, [h, v]])
        x, y = view.intraop_dots[k].getData()
        assert np.allclose(np.c_[x, y], intraop.xyz[:, [h, v]])
        x, y = view.pair_lines[k].getData()
        assert len(x) == 2 * len(intraop)
    assert view.preop_dots[0].opts["symbol"] != view.intraop_dots[0].opts["symbol"]
    preop_texts, intraop_texts = view.label_texts(0)
    assert preop_texts == preop.ids and intraop_texts == intraop.ids
    panel.shutdown()


def test_wider_bounds_reach_a_far_rotation(qtbot, panel, pelvic_nodes, tmp_path):
    preop, intraop, truth = moved_case(pelvic_nodes, 120.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    assert "widen the rotation" in click_run_refused(qtbot, panel)        # 120 deg is outside +-60 deg
    panel.rotation_bound.setValue(150.0)
    assert np.array_equal(click_run(qtbot, panel).pairing, truth)


def test_labels_checkbox_forbids_side_crossings(qtbot, panel, pelvic_nodes, tmp_path):
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    swapped = [label.replace(" R", " x").replace(" L", " R").replace(" x", " L") for label in intraop.labels]
    intraop = NodeSet(intraop.ids, swapped, intraop.xyz, frame="trocar")
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    assert np.array_equal(click_run(qtbot, panel).pairing, truth)          # geometry alone: the truth
    panel.labels_check.setChecked(True)                                    # no pairing keeps the sides: said so
    assert "check the labels" in click_run_refused(qtbot, panel)


def test_manual_alignment_moves_the_preop_view_and_solves_a_far_case(qtbot, panel, pelvic_nodes, tmp_path):
    preop, intraop, truth = moved_case(pelvic_nodes, 120.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    assert np.allclose(panel.view.scene_shown.preop.xyz.mean(axis=0), intraop.xyz.mean(axis=0))  # centroids matched
    click_run_refused(qtbot, panel)                                        # 120 deg is beyond +-60 deg
    align = panel.alignment
    align.angle_spins["yaw"].setValue(120.0)
    shown = panel.view.scene_shown
    assert shown.pairing is None                                           # inputs changed: result no longer drawn
    assert np.allclose(shown.preop.xyz.mean(axis=0), intraop.xyz.mean(axis=0))   # turned about its own centroid
    assert np.allclose(shown.preop.xyz - shown.preop.xyz.mean(axis=0),
                       (preop.xyz - preop.xyz.mean(axis=0)) @ geometry.rotation_from_euler(120, 0, 0).T)
    result = click_run(qtbot, panel)
    assert np.array_equal(result.pairing, truth) and result.rms_mm < 3.0
    align.shift_spins["x"].setValue(10.0)                                  # the shift is from the intraop centroid
    assert np.allclose(panel.view.scene_shown.preop.xyz.mean(axis=0), intraop.xyz.mean(axis=0) + [10.0, 0.0, 0.0])
    qtbot.mouseClick(align.reset_button, Qt.MouseButton.LeftButton)
    assert np.allclose(panel.view.scene_shown.preop.xyz, preop.xyz - preop.xyz.mean(axis=0) + intraop.xyz.mean(axis=0))


def test_initial_transform_turns_about_the_centre_then_shifts():
    centre, shift = np.array([10.0, -20.0, 30.0]), np.array([5.0, 6.0, -7.0])
    transform = initial_transform(30.0, -10.0, 45.0, shift, centre)
    assert np.allclose(geometry.apply(transform, centre[None]), centre + shift)
    assert np.allclose(transform[:3, :3], geometry.rotation_from_euler(30.0, -10.0, 45.0))


def test_spect_threshold_slider_changes_the_node_count(qtbot, panel, tmp_path):
    # Two nodes 20 mm apart, the second at half the activity, and a third far away.
    sources = np.array([[-20.0, 50.0, 55.0], [0.0, 50.0, 55.0], [40.0, 60.0, 40.0]])
    counts, origin = spect_of_nodes(sources, activity=[1.0, 0.5, 1.0], shape=(40, 48, 48), seed=1)
    path = write_nm(counts, origin, 4.795, tmp_path / "spect.dcm")[0]
    box = panel.preop_box
    panel.load_preop(path)
    qtbot.waitUntil(lambda: not panel.busy and box.nodes is not None, timeout=TIMEOUT_MS)
    assert len(box.nodes) == 3 and "3 nodes above 0.30" in box.status.text()
    assert box.table.rowCount() == 3 and box.threshold_slider.isEnabled()
    found = [min(np.linalg.norm(box.nodes.xyz - s, axis=1)) for s in sources]
    assert max(found) < 5.0
    emitted = []
    box.nodes_changed.connect(emitted.append)
    for percent in (40, 50, 60):                                           # a drag: one re-segmentation
        box.threshold_slider.setValue(percent)
    assert box.threshold_label.text() == "0.60 x max"
    qtbot.waitUntil(lambda: not panel.busy and len(emitted) == 1, timeout=TIMEOUT_MS)
    assert len(box.nodes) == 2 and "2 nodes above 0.60" in box.status.text()
    assert min(np.linalg.norm(box.nodes.xyz - sources[1], axis=1)) > 10.0   # the weaker node is gone
    box.threshold_slider.setValue(30)
    box.count_spin.setValue(1)
    qtbot.waitUntil(lambda: not panel.busy and len(box.nodes) == 1, timeout=TIMEOUT_MS)
    assert len(emitted) == 2


def test_unreadable_preop_is_one_sentence(qtbot, panel, tmp_path):
    panel.load_preop(tmp_path / "missing.csv")
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    text = panel.preop_box.status.text()
    assert "no such file" in text and text.endswith(".") and "\n" not in text


def test_missing_or_too_few_nodes_give_a_sentence_not_a_crash(qtbot, panel, pelvic_nodes, tmp_path):
    xyz, labels = pelvic_nodes
    qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    assert panel.message.text().startswith("Load the preop nodes first")
    load_preop(qtbot, panel, NodeSet.from_xyz(xyz[:2], labels[:2]), tmp_path / "two.csv")
    qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    assert panel.message.text().startswith("There are no intraop nodes")
    panel.set_intraop_nodes(NodeSet.from_xyz(xyz, labels))
    qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    assert panel.message.text() == ("Only 2 preop nodes; registration needs at least 3: lower the SPECT threshold or "
                                    "open another node file.")
    assert panel.last_result is None and panel.run_button.isEnabled()
    assert not any(button.isEnabled() for button in panel.export_buttons.values())


def test_too_few_intraop_nodes_say_what_is_true(qtbot, panel, pelvic_nodes, tmp_path):
    """Issue 28: one node stored and none excluded was "Fewer than 3 intraop nodes are left once the excluded ones are
    taken out"; it says how many there are and what to do, and names the excluded nodes only when there are some."""
    preop, intraop, _ = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(NodeSet(intraop.ids[:1], intraop.labels[:1], intraop.xyz[:1]))
    qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    assert panel.message.text() == ("Only 1 intraop node so far; registration needs at least 3: store 2 more (or open "
                                    "a node file with more).")
    panel.set_intraop_nodes(NodeSet(intraop.ids[:4], intraop.labels[:4], intraop.xyz[:4]))
    click_run(qtbot, panel)
    for excluded in range(2):                                      # leave out the first row, then the next first
        panel.pairing_table.selectRow(0)
        qtbot.mouseClick(panel.exclude_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    assert panel.message.text() == (f"Only 2 intraop nodes left once {intraop.ids[0]}, {intraop.ids[1]} are left out; "
                                    "registration needs at least 3: include some (Include all) or store more.")


@pytest.mark.slow
def test_exports_are_written_and_read_back(qtbot, panel, pelvic_nodes, tmp_path, monkeypatch):
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    extra = NodeSet(intraop.ids + ["I7"], intraop.labels + ["PR L"], np.vstack([intraop.xyz, [[250.0, 250, 250]]]))
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(extra)
    result = click_run(qtbot, panel)
    assert np.array_equal(result.pairing, np.append(truth, -1))
    targets = {"pairs": tmp_path / "pairs.csv", "slicer": tmp_path / "preop_in_trocar.mrk.json",
               "report": tmp_path / "report"}                             # no suffix: .png is added
    for kind, target in targets.items():
        monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *args, t=target: (str(t), ""))
        qtbot.mouseClick(panel.export_buttons[kind], Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: not panel.busy and panel.message.text().startswith("Written"), timeout=TIMEOUT_MS)
        panel.message.clear()
    assert not list(tmp_path.glob(".~*"))                          # written under a hidden name, then renamed
    lines = targets["pairs"].read_text(encoding="utf-8").splitlines()
    rows = list(csv.DictReader(line for line in lines if not line.startswith("#")))
    assert [r["intraop_id"] for r in rows] == extra.ids
    assert [r["hot_spot"] for r in rows] == [preop.ids[n] for n in truth] + [""]
    markups = read_nodes(targets["slicer"])
    assert markups.ids == preop.ids and markups.labels == preop.labels
    assert np.allclose(markups.xyz, geometry.apply(result.transform, preop.xyz))
    png = (tmp_path / "report.png").read_bytes()
    assert struct.unpack(">I", png[16:20])[0] == round(REPORT_SIZE_IN[0] * REPORT_DPI)
    assert read_report_metadata(tmp_path / "report.json")["n_extra"] == 1      # the sidecar beside it


def test_the_report_is_written_in_a_worker_beside_the_session_with_its_case_and_calibration(
        qtbot, panel, pelvic_nodes, tmp_path, monkeypatch):
    preop, intraop, _ = moved_case(pelvic_nodes, 20.0)
    folder = tmp_path / "cases"
    folder.mkdir()
    with Session.create(folder / "case-7.h5", case_id="case-7") as session:
        session.set_calibration(stereo=thesis_calibration(), chain=ChainCalibration.manual())
        for k in range(len(intraop)):
            session.add_intraop_node(intraop.ids[k], intraop.labels[k], intraop.xyz[k])
        panel.set_session(session)
        load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
        click_run(qtbot, panel)
        starts = []
        monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda _parent, _title, start, _filter: (
            starts.append(start) or start, ""))
        qtbot.mouseClick(panel.export_buttons["report"], Qt.MouseButton.LeftButton)
        assert panel.export_progress.isVisible() and panel.busy             # busy dialog; the GUI thread is free
        assert not panel.export_buttons["report"].isEnabled()
        qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
        assert not panel.export_progress.isVisible() and panel.export_buttons["report"].isEnabled()
    assert starts == [str(folder.resolve() / "case-7_global_report.png")]
    meta = read_report_metadata(folder / "case-7_global_report.png")
    assert meta == read_report_metadata(folder / "case-7_global_report.json")
    assert meta["case_id"] == "case-7" and meta["session_file"] == "case-7.h5" and meta["method"] == "global"
    assert meta["stereo_rms_px"] is not None and meta["trocar_camera_mm"] == pytest.approx(158.0)
    assert meta["stereo_version"] and meta["chain_version"]


def test_export_to_an_unwritable_place_is_one_sentence_in_a_box(qtbot, panel, pelvic_nodes, tmp_path, monkeypatch):
    preop, intraop, _ = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    click_run(qtbot, panel)
    monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *a: (str(tmp_path / "no" / "such" / "pairs.csv"), ""))
    qtbot.mouseClick(panel.export_buttons["pairs"], Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not panel.busy and "cannot write" in panel.message.text(), timeout=TIMEOUT_MS)
    assert panel.message.text().endswith("choose another folder.")
    assert panel.export_problem.isVisible() and panel.export_problem.text() == panel.message.text()


def test_writable_session_stores_preop_and_result_review_only_shows(qtbot, panel, pelvic_nodes, tmp_path):
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    path = tmp_path / "case.h5"
    with Session.create(path, case_id="gui-reg-01") as session:
        for k in range(len(intraop)):
            session.add_intraop_node(intraop.ids[k], intraop.labels[k], intraop.xyz[k])
        panel.set_session(session)
        assert panel.intraop_table.rowCount() == len(intraop)
        load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
        result = click_run(qtbot, panel)
        assert panel.message.text() == "Stored in the session as registration 0."
    stored = Session.open(path)
    assert len(stored.registrations()) == 1
    assert np.array_equal(stored.registrations()[0].result.pairing, truth)
    assert np.allclose(stored.registrations()[0].result.transform, result.transform)
    assert stored.preop_nodes().ids == preop.ids

    review = RegistrationPanel()
    qtbot.addWidget(review)
    review.set_session(stored)
    assert review.preop_box.nodes.ids == preop.ids
    assert np.array_equal(review.last_result.pairing, truth)
    assert table_column(review.pairing_table, 2) == [preop.ids[n] for n in truth]
    click_run(qtbot, review)
    assert review.message.text().startswith("Review session: the result is shown but not stored")
    review.shutdown()
    stored.close()
    assert len(Session.open(path).registrations()) == 1


def test_set_session_none_clears(qtbot, panel, pelvic_nodes, tmp_path):
    preop, intraop, _ = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    click_run(qtbot, panel)
    panel.set_session(None)
    assert panel.last_result is None and panel.pairing_table.rowCount() == 0
    assert panel.intraop_table.rowCount() == 0 and panel.view.scene_shown.intraop is None


def test_offscreen_has_no_opengl_view(qtbot):
    if QGuiApplication.platformName() != "offscreen":
        pytest.skip("only the offscreen platform is known to lack OpenGL")
    assert node_views.opengl_available() is False
    view = make_node_view()
    qtbot.addWidget(view)
    assert view.kind == "three-view"


def test_view_falls_back_to_three_views_when_opengl_breaks(qtbot, monkeypatch):
    monkeypatch.setattr(node_views, "opengl_available", lambda: True)

    def broken(*args):
        raise RuntimeError("no OpenGL 2.0 context")

    monkeypatch.setattr(node_views, "NodeView3D", broken)
    view = make_node_view()
    qtbot.addWidget(view)
    assert view.kind == "three-view"


def test_missing_nodes_leave_one_out_and_exclude_rerun(qtbot, panel, pelvic_nodes, tmp_path):
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    found = [m for m in range(len(intraop)) if truth[m] not in (2, 4)]      # P3 and P5 not found yet
    partial = NodeSet([intraop.ids[m] for m in found], [intraop.labels[m] for m in found], intraop.xyz[found],
                      frame="trocar")
    panel.set_intraop_nodes(partial)
    with qtbot.waitSignal(panel.missing_changed) as missing:
        result = click_run(qtbot, panel)
    assert [t.preop_id for t in missing.args[0]] == ["P3", "P5"]
    assert "P3" in panel.missing_label.text() and "P5" in panel.missing_label.text()
    state = panel.navigation                                          # what the feeds draw: current, P3 and P5
    assert [t.preop_id for t in state.targets] == ["P3", "P5"] and not state.stale
    assert set(state.found) == {panel.preop_box.nodes.ids[truth[m]] for m in found}
    assert state.confident == bool(np.all(result.confidence >= 0.95))
    with qtbot.waitSignal(panel.missing_changed) as cleared:            # inputs changed: no stale guidance
        panel.rotation_bound.setValue(59.0)
    assert cleared.args[0] == [] and panel.missing_label.text() == "" and panel.missing_nodes == []
    assert panel.navigation.stale and panel.navigation.banner() == panel.navigation.stale   # greyed on the feeds
    result = click_run(qtbot, panel)
    loo_column = PAIR_COLUMNS.index("leave-one-out mm")
    assert [float(v) for v in table_column(panel.pairing_table, loo_column)] == pytest.approx(
        result.leave_one_out_mm, abs=0.051)
    panel.pairing_table.selectRow(0)
    excluded = partial.ids[0]
    with qtbot.waitSignal(panel.registered, timeout=TIMEOUT_MS) as rerun:
        qtbot.mouseClick(panel.exclude_button, Qt.MouseButton.LeftButton)
    assert len(rerun.args[0].pairing) == len(partial) - 1
    assert table_column(panel.pairing_table, 0) == partial.ids[1:] and excluded in panel.message.text()
    with qtbot.waitSignal(panel.registered, timeout=TIMEOUT_MS) as back:
        qtbot.mouseClick(panel.include_button, Qt.MouseButton.LeftButton)
    assert len(back.args[0].pairing) == len(partial) and not panel.include_button.isEnabled()


def test_the_panel_registers_again_after_each_stored_node_when_it_says_so(qtbot, panel, pelvic_nodes, tmp_path):
    session, intraop = three_stored(qtbot, panel, pelvic_nodes, tmp_path, "phantom-03")
    assert panel.auto_rerun.isChecked()
    session.add_intraop_node(intraop.ids[3], intraop.labels[3], intraop.xyz[3])
    with qtbot.waitSignal(panel.registered, timeout=TIMEOUT_MS) as first:
        panel.rerun_after_store()
    assert len(first.args[0].pairing) == 4 and len(panel.missing_nodes) == 2
    assert session.registrations() == [] and panel.run_button.isEnabled()    # only Run stores the one that counts
    panel.auto_rerun.setChecked(False)
    session.add_intraop_node(intraop.ids[4], intraop.labels[4], intraop.xyz[4])
    with qtbot.assertNotEmitted(panel.registered, wait=300):
        panel.rerun_after_store()
    assert panel.intraop_table.rowCount() == 5                                  # the nodes still follow the session
    session.close()


def wheel_over(widget, steps: int = 3) -> None:
    """A mouse-wheel turn of ``steps`` notches (up) over the middle of ``widget``, through the application."""
    from PySide6.QtCore import QPoint, QPointF
    from PySide6.QtGui import QWheelEvent
    from PySide6.QtWidgets import QApplication
    centre = QPointF(widget.rect().center())
    event = QWheelEvent(centre, QPointF(widget.mapToGlobal(centre)), QPoint(0, 0), QPoint(0, 120 * steps),
                        Qt.MouseButton.NoButton, Qt.KeyboardModifier.NoModifier, Qt.ScrollPhase.NoScrollPhase, False)
    QApplication.sendEvent(widget, event)


def test_wheel_over_an_unfocused_spin_box_changes_nothing(qtbot, qapp, panel):
    from snreg_gui.common import wheel_guard
    wheel_guard.install(qapp)
    panel.show()
    qtbot.waitExposed(panel)
    spin = panel.rotation_bound
    assert spin.focusPolicy() == Qt.FocusPolicy.StrongFocus and not spin.hasFocus()
    wheel_over(spin)
    wheel_over(panel.method_combo)
    wheel_over(panel.preop_box.threshold_slider)
    assert spin.value() == 60.0 and panel.method_combo.currentIndex() == 0
    assert panel.preop_box.threshold_slider.focusPolicy() == Qt.FocusPolicy.StrongFocus
    panel.activateWindow()
    spin.setFocus()
    qtbot.waitUntil(spin.hasFocus, timeout=TIMEOUT_MS)
    wheel_over(spin)                                    # clicked into, the wheel works as usual
    assert spin.value() == 63.0


def test_a_spin_box_made_after_the_guard_is_guarded_and_no_other_widget_s_events_pass_through_it(qtbot, qapp,
                                                                                                  monkeypatch):
    """Issue 36: the guard was an application-wide filter in Python: every event of every widget (paints, timers,
    queued signals) took the interpreter lock on the GUI thread. Now only the guarded widgets' events reach it, and a
    widget made after it is installed is guarded as it is polished."""
    from PySide6.QtWidgets import QLabel, QSpinBox, QVBoxLayout, QWidget

    from snreg_gui.common import wheel_guard
    seen = []

    class Counting(wheel_guard.WheelGuard):          # a subclass: a Qt method patched on the class crashed later
        def eventFilter(self, obj, event) -> bool:    # noqa: N802 (Qt's name)
            seen.append(obj)
            return super().eventFilter(obj, event)
    monkeypatch.setattr(wheel_guard, "WheelGuard", Counting)
    monkeypatch.setattr(wheel_guard, "_guard", None)     # a guard of its own, one that counts what it filters
    wheel_guard.install(qapp)
    window = QWidget()
    qtbot.addWidget(window)
    spin, label = QSpinBox(), QLabel("0")
    for widget in (spin, label):
        QVBoxLayout(window).addWidget(widget) if window.layout() is None else window.layout().addWidget(widget)
    spin.setValue(5)
    window.show()
    qtbot.waitExposed(window)
    assert spin.focusPolicy() == Qt.FocusPolicy.StrongFocus and not spin.hasFocus()
    wheel_over(spin)
    assert spin.value() == 5 and any(obj is spin for obj in seen)
    for k in range(20):
        label.setText(str(k))
        label.repaint()
    assert not any(obj is label or obj is window for obj in seen)


def test_changed_inputs_grey_the_result_and_disable_exports_until_the_next_run(qtbot, panel, pelvic_nodes, tmp_path):
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(intraop)
    click_run(qtbot, panel)
    buttons = list(panel.export_buttons.values())
    assert all(b.isEnabled() for b in buttons) and panel.pairing_table.isEnabled()
    renumbered = NodeSet([f"SN{k + 1}" for k in reversed(range(len(preop)))], preop.labels, preop.xyz)
    load_preop(qtbot, panel, renumbered, tmp_path / "renumbered.csv")
    assert not any(b.isEnabled() for b in buttons) and not panel.pairing_table.isEnabled()
    assert panel.summary.text().startswith("OUT OF DATE")
    assert panel.last_result is not None and panel.current_result is None     # shown, but not sent as current
    click_run(qtbot, panel)
    assert all(b.isEnabled() for b in buttons) and panel.pairing_table.isEnabled()
    assert panel.current_result is panel.last_result is not None
    assert table_column(panel.pairing_table, 2) == [renumbered.ids[n] for n in truth]
    for change in (lambda: panel.method_combo.setCurrentText("icp"), lambda: panel.labels_check.toggle(),
                   lambda: panel.rotation_bound.setValue(30.0), lambda: panel.translation_bound.setValue(30.0)):
        change()
        assert not any(b.isEnabled() for b in buttons) and not panel.pairing_table.isEnabled()
        click_run(qtbot, panel)
        assert all(b.isEnabled() for b in buttons)


@pytest.mark.parametrize("method", ["global", "chamfer"])
def test_a_far_or_extra_node_is_warned_about_in_words(qtbot, panel, pelvic_nodes, tmp_path, method):
    preop, intraop, _ = moved_case(pelvic_nodes, 20.0)
    far = NodeSet(intraop.ids + ["I7"], intraop.labels + [""], np.vstack([intraop.xyz, intraop.xyz[0] + [372.0, 0, 0]]))
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    panel.set_intraop_nodes(far)
    panel.method_combo.setCurrentText(method)
    click_run(qtbot, panel)
    warnings = [line for line in panel.summary.text().splitlines() if line.startswith("WARNING: ")]
    assert len(warnings) == 1 and warnings[0].startswith("WARNING: I7 ")
    panel.set_intraop_nodes(intraop)
    click_run(qtbot, panel)
    assert "WARNING" not in panel.summary.text()


def test_each_method_has_a_one_sentence_tooltip(panel):
    combo = panel.method_combo
    methods = [combo.itemText(k) for k in range(combo.count())]
    assert sorted(methods) == ["chamfer", "cpd", "global", "icp"]
    for k in range(combo.count()):
        tip = combo.itemData(k, Qt.ItemDataRole.ToolTipRole)
        assert tip and tip.endswith(".") and tip.count(". ") == 0
    combo.setCurrentText("chamfer")
    assert combo.toolTip() == combo.itemData(combo.currentIndex(), Qt.ItemDataRole.ToolTipRole)


def _overlaps(boxes) -> list:
    """Pairs of (left, top, right, bottom) boxes that overlap by more than half a pixel each way."""
    return [(a, b) for a in range(len(boxes)) for b in range(a + 1, len(boxes))
            if min(boxes[a][2], boxes[b][2]) - max(boxes[a][0], boxes[b][0]) > 0.5
            and min(boxes[a][3], boxes[b][3]) - max(boxes[a][1], boxes[b][1]) > 0.5]


def test_three_view_labels_of_clustered_nodes_do_not_overlap_and_a_far_node_is_in_range(qtbot, monkeypatch):
    """Issue 14: labels overlapped into "SNSNSN4" and a node 372 mm away fell outside the view."""
    monkeypatch.setattr(node_views, "opengl_available", lambda: False)
    view = make_node_view()
    qtbot.addWidget(view)
    view.resize(1000, 450)
    view.show()
    qtbot.waitExposed(view)
    rng = np.random.default_rng(3)
    preop = NodeSet.from_xyz(rng.normal([0.0, 0.0, 250.0], 3.0, (5, 3)), prefix="P")
    far = np.vstack([preop.xyz[:4] + rng.normal(0.0, 1.0, (4, 3)), [[372.0, 0.0, 250.0]]])
    view.show_scene(node_views.NodeScene(preop, NodeSet.from_xyz(far), np.array([0, 1, 2, 3, -1]),
                                         np.array([0, 0, 0, 0, 1], bool)))
    for k in range(3):
        boxes = view.label_boxes(k)
        assert len(boxes) == 10 and _overlaps(boxes) == []
        (x0, x1), (y0, y1) = view.plots[k].vb.viewRange()
        h, v = [(0, 1), (0, 2), (1, 2)][k]
        assert x0 < far[4, h] < x1 and y0 < far[4, v] < y1
    assert "not found yet" in view.legend.text and "intraop" in view.legend.text and "paired" in view.legend.text
    assert len(view.missing_dots[0].getData()[0]) == 1 and len(view.preop_dots[0].getData()[0]) == 4


def test_colliding_preop_ids_are_shown_marked(qtbot, panel, pelvic_nodes, tmp_path, monkeypatch):
    """A preop node file using SN1... like the intraop nodes: the panel, its summary and the view say P:SN..."""
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    preop.ids = [f"SN{k + 1}" for k in range(len(preop))]
    intraop.ids = [f"SN{k + 1}" for k in range(len(intraop))]
    load_preop(qtbot, panel, preop, tmp_path / "sn_preop.csv")
    panel.set_intraop_nodes(intraop)
    click_run(qtbot, panel)
    assert table_column(panel.pairing_table, 0) == intraop.ids
    assert table_column(panel.pairing_table, 2) == [f"P:SN{n + 1}" for n in truth]
    preop_texts, intraop_texts = panel.view.scene_shown.texts()
    assert preop_texts == [f"P:{i}" for i in preop.ids] and intraop_texts == intraop.ids
    assert panel.preop_box.nodes.ids == preop.ids          # only what is shown is marked


def test_node_view_takes_at_least_40_percent_of_the_tab(qtbot, panel):
    panel.resize(1024, 640)
    panel.show()
    qtbot.waitExposed(panel)
    qtbot.waitUntil(lambda: panel.view.height() >= 0.4 * panel.height(), timeout=TIMEOUT_MS)


def test_final_mark_is_kept_in_the_session_and_the_exports_use_it(qtbot, panel, pelvic_nodes, tmp_path, monkeypatch):
    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    path = tmp_path / "final.h5"
    with Session.create(path, case_id="gui-final-01") as session:
        for k in range(len(intraop)):
            session.add_intraop_node(intraop.ids[k], intraop.labels[k], intraop.xyz[k])
        panel.set_session(session)
        load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
        panel.method_combo.setCurrentText("icp")
        click_run(qtbot, panel)
        panel.method_combo.setCurrentText("cpd")
        click_run(qtbot, panel)
        stored = panel.stored
        assert stored.table.rowCount() == 2 and not stored.unmark_button.isEnabled()
        assert "exports write the result shown" in panel.final_label.text()
        stored.table.selectRow(0)
        qtbot.mouseClick(stored.mark_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: session.final_registration() == 0, timeout=TIMEOUT_MS)
        qtbot.waitUntil(lambda: stored.table.item(0, 4).text() == "FINAL", timeout=TIMEOUT_MS)
        assert stored.table.item(1, 4).text() == "" and "registration 0, marked final" in panel.final_label.text()
        load_preop(qtbot, panel, NodeSet(preop.ids, preop.labels, preop.xyz + 5.0), tmp_path / "moved.csv")
        assert not panel.pairing_table.isEnabled()                      # the shown result is out of date...
        assert panel.export_buttons["pairs"].isEnabled()                # ...but the final one can be exported
        monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *a: (str(tmp_path / "pairs.csv"), ""))
        qtbot.mouseClick(panel.export_buttons["pairs"], Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: not panel.busy and panel.message.text().startswith("Written"), timeout=TIMEOUT_MS)
        assert "(registration 0, marked final)" in panel.message.text()
        text = (tmp_path / "pairs.csv").read_text(encoding="utf-8")
        assert "# registration: registration 0 of the session, marked final" in text and "# method: icp" in text
        rows = list(csv.DictReader(line for line in text.splitlines() if not line.startswith("#")))
        assert [r["hot_spot"] for r in rows] == [preop.ids[n] for n in truth]
        qtbot.mouseClick(stored.unmark_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: session.final_registration() is None, timeout=TIMEOUT_MS)
        qtbot.waitUntil(lambda: not panel.export_buttons["pairs"].isEnabled(), timeout=TIMEOUT_MS)
    with Session.open(path) as reopened:
        assert reopened.final_registration() is None and len(reopened.registrations()) == 2


@pytest.mark.parametrize("width", [560, 900])
def test_the_three_projections_lie_inside_their_view_however_narrow_with_the_legend_wrapped(qtbot, width):
    """At 1024x700 the legend, one line, held the views wider than their pane: the third projection was cut."""
    view = ThreeViewPlot()
    qtbot.addWidget(view)
    view.resize(width, 350)
    view.show()
    qtbot.waitExposed(view)
    qtbot.waitUntil(lambda: max(plot.sceneBoundingRect().right() for plot in view.plots) <= view.width(),
                    timeout=5_000)
    assert view.legend.sceneBoundingRect().right() <= view.width()


def test_the_feeds_say_updating_only_while_a_run_will_answer_else_out_of_date(qtbot, panel, pelvic_nodes, tmp_path,
                                                                               monkeypatch):
    """Greyed hot spots say why: "updating" while a registration runs, "out of date: ... register again" when none
    will (inputs changed by hand, a run that failed); a result that no longer answers the inputs is never sent as
    current, not even for a moment."""
    from snreg.workflow.navigation import UPDATING
    from snreg_gui.registration import runs
    from snreg_gui.registration.navigation import OUT_OF_DATE

    preop, intraop, truth = moved_case(pelvic_nodes, 20.0)
    load_preop(qtbot, panel, preop, tmp_path / "preop.csv")
    found = [m for m in range(len(intraop)) if truth[m] not in (2, 4)]
    panel.set_intraop_nodes(NodeSet([intraop.ids[m] for m in found], [intraop.labels[m] for m in found],
                                    intraop.xyz[found], frame="trocar"))
    click_run(qtbot, panel)
    assert panel.auto_rerun.isChecked() and panel.navigation.targets and not panel.navigation.stale
    sent = []
    panel.navigation_changed.connect(sent.append)
    panel.rotation_bound.setValue(59.0)                    # no run follows a change by hand
    assert panel.navigation.stale == OUT_OF_DATE and [s.stale for s in sent] == [OUT_OF_DATE]
    sent.clear()
    click_run(qtbot, panel)
    assert [s.stale for s in sent] == [UPDATING, ""]       # greyed while it runs, then the new result, current
    sent.clear()

    def broken(*_):
        raise ValueError("the solver broke")

    monkeypatch.setattr(runs, "run_from", broken)
    panel.rotation_bound.setValue(58.0)
    qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: "solver broke" in panel.message.text(), timeout=TIMEOUT_MS)
    assert panel.navigation.stale == OUT_OF_DATE            # nothing is updating once the run failed
    assert [s.stale for s in sent] == [OUT_OF_DATE, UPDATING, OUT_OF_DATE]


def test_an_undo_that_leaves_too_few_nodes_to_register_says_out_of_date_not_updating(qtbot, panel, pelvic_nodes,
                                                                                        tmp_path):
    from snreg_gui.registration.navigation import OUT_OF_DATE

    session, intraop = three_stored(qtbot, panel, pelvic_nodes, tmp_path, "phantom-04")
    session.add_intraop_node(intraop.ids[3], intraop.labels[3], intraop.xyz[3])
    with qtbot.waitSignal(panel.registered, timeout=TIMEOUT_MS):
        panel.rerun_after_store()
    assert panel.navigation.targets and not panel.navigation.stale
    session.remove_intraop_node(intraop.ids[3])
    session.remove_intraop_node(intraop.ids[2])             # two undone: two nodes left, no run can follow
    with qtbot.assertNotEmitted(panel.registered, wait=300):
        panel.rerun_after_store()
    assert panel.navigation.stale == OUT_OF_DATE and panel.navigation.banner() == OUT_OF_DATE
    session.close()


def test_a_store_behind_another_tab_draws_nothing_until_the_registration_tab_is_shown(qtbot, panel, pelvic_nodes,
                                                                                     tmp_path, monkeypatch):
    """Issue 36: each store and each automatic registration redrew the hidden registration tab's view (markers,
    ellipses, labels) on the GUI thread during acquisition. Hidden, the view keeps the newest scene and draws nothing,
    its markers and labels still the old ones; shown, it draws that scene before it is painted: the new node's marker
    where it is, labelled beside it, clear of the others."""
    from PySide6.QtWidgets import QLabel, QTabWidget

    from snreg_gui.common import three_view

    if not isinstance(panel.view, ThreeViewPlot):
        pytest.skip("the labels placed in Python are the three projections' (no OpenGL here)")
    placed = []
    real = three_view.place_labels
    monkeypatch.setattr(three_view, "place_labels", lambda *a, **k: placed.append(1) or real(*a, **k))
    tabs = QTabWidget()
    qtbot.addWidget(tabs)
    tabs.addTab(QLabel("acquisition"), "Acquisition")
    tabs.addTab(panel, "Registration")
    tabs.resize(1024, 700)
    tabs.show()
    qtbot.waitExposed(tabs)
    session, intraop = three_stored(qtbot, panel, pelvic_nodes, tmp_path, "gui-hidden-01")
    tabs.setCurrentWidget(panel)                         # the three stored nodes drawn, then the tab hidden again
    qtbot.waitUntil(lambda: panel.view.isVisible() and not panel.view.stale, timeout=TIMEOUT_MS)
    tabs.setCurrentIndex(0)
    qtbot.waitUntil(lambda: not panel.view.isVisible(), timeout=TIMEOUT_MS)
    drawn, old_intraop = panel.view.scenes_drawn, panel.view.intraop_dots[0].getData()
    placed.clear()
    session.add_intraop_node(intraop.ids[3], intraop.labels[3], intraop.xyz[3])     # a store, as the app sees it
    panel.refresh_intraop()
    panel.run()                                          # and a registration of the four, as after a store
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    assert panel.current_result is not None and len(panel.current_result.pairing) == 4
    assert placed == [] and panel.view.scenes_drawn == drawn and panel.view.stale      # nothing drawn while hidden
    assert np.array_equal(panel.view.intraop_dots[0].getData()[0], old_intraop[0])     # still the three
    assert intraop.ids[3] in panel.view.scene_shown.intraop.ids and panel.view.scene_shown.pairing is not None
    tabs.setCurrentWidget(panel)
    qtbot.waitUntil(lambda: panel.view.isVisible() and not panel.view.stale, timeout=TIMEOUT_MS)
    assert placed and panel.view.scenes_drawn == drawn + 1                 # the newest scene only, once
    x, y = panel.view.intraop_dots[0].getData()
    assert np.allclose(np.c_[x, y], intraop.xyz[:4, :2])
    assert "paired" in panel.view.legend.text                             # the registration's scene, not the store's
    for k, (h, v) in enumerate([(0, 1), (0, 2), (1, 2)]):
        boxes = panel.view.label_boxes(k)
        assert _overlaps(boxes) == []
        preop_texts, intraop_texts = panel.view.label_texts(k)
        assert intraop.ids[3] in intraop_texts
        new = boxes[len(preop_texts) + intraop_texts.index(intraop.ids[3])]
        marker = panel.view.plots[k].vb.mapViewToScene(pg_point(intraop.xyz[3, h], intraop.xyz[3, v]))
        gap = max(new[0] - marker.x(), marker.x() - new[2], new[1] - marker.y(), marker.y() - new[3])
        assert 0 < gap < 60, (k, gap)                    # beside its own marker, not on it, not far from it
    panel.setParent(None)                                # the fixture's panel outlives the tabs
    session.close()


def pg_point(x: float, y: float):
    from PySide6.QtCore import QPointF
    return QPointF(float(x), float(y))
