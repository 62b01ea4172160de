"""Preop landmarks from a file of their own (issue 29): the preop box's "Landmarks..." and "clear", on a seeded SPECT and
a 3D Slicer point list saved in RAS; the reading rules (Qt-free) they share with ``snreg register --preop-landmarks``."""

import json

import numpy as np
import pytest
from PySide6.QtCore import Qt

from snreg.demo.spect import spect_of_nodes, write_nm
from snreg.errors import NodeFileError
from snreg.nodes import NodeSet, write_nodes
from snreg.session import Session
from snreg.workflow.preop_landmarks import read_preop_landmarks
from snreg_gui.common import file_places

TIMEOUT_MS = 15_000
THREE = ("aortic bifurcation", "right common iliac bifurcation", "left common iliac bifurcation")
CT_LPS = np.array([[2.0, 40.0, 120.0], [-35.0, 55.0, 75.0], [38.0, 52.0, 78.0]])     # mm, patient LPS
SOURCES_LPS = np.array([[-30.0, 50.0, 55.0], [30.0, 50.0, 55.0], [0.0, 75.0, 30.0], [-5.0, 30.0, 85.0]])


def slicer_points(path, names, xyz, system: str):
    """A 3D Slicer point list (.mrk.json) as Slicer saves it, positions in ``system`` (RAS or LPS)."""
    points = [{"id": str(k + 1), "label": name, "description": "", "position": [float(v) for v in p]}
              for k, (name, p) in enumerate(zip(names, xyz))]
    path.write_text(json.dumps({"@schema": "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/"
                                           "Markups/Resources/Schema/markups-schema-v1.0.3.json#",
                                "markups": [{"type": "Fiducial", "coordinateSystem": system,
                                             "controlPoints": points}]}))
    return path


def ras(lps):
    return np.asarray(lps) * [-1.0, -1.0, 1.0]


@pytest.fixture
def spect(tmp_path):
    """Four hot spots (LPS mm) in a small seeded NM volume."""
    counts, origin = spect_of_nodes(SOURCES_LPS, shape=(40, 48, 48), seed=2)
    return write_nm(counts, origin, 4.795, tmp_path / "spect.dcm")[0]


def wait_idle(qtbot, panel):
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)


def test_a_ras_point_list_gives_lps_landmarks_beside_a_spect_kept_when_resegmented_and_saved(qtbot, panel, spect,
                                                                                             tmp_path, monkeypatch):
    box = panel.preop_box
    with Session.create(tmp_path / "s.h5", case_id="lm-file") as session:
        panel.set_session(session)
        panel.load_preop(spect)
        qtbot.waitUntil(lambda: not panel.busy and box.nodes is not None, timeout=TIMEOUT_MS)
        assert box.landmarks is None and not box.clear_landmarks_button.isEnabled()      # a SPECT gives none
        assert box.status.text() == "4 nodes above 0.30 x maximum in spect.dcm"
        marks = slicer_points(tmp_path / "ct.mrk.json", THREE, ras(CT_LPS), "RAS")
        monkeypatch.setattr(file_places, "choose_file", lambda *_: str(marks))
        with qtbot.waitSignal(box.landmarks_changed, timeout=TIMEOUT_MS):
            qtbot.mouseClick(box.landmarks_button, Qt.MouseButton.LeftButton)
        assert box.landmarks.ids == list(THREE) and box.landmarks.frame == "LPS"
        np.testing.assert_allclose(box.landmarks.xyz, CT_LPS)                           # RAS turned to LPS
        assert box.status.text() == "4 nodes above 0.30 x maximum in spect.dcm; 3 landmarks from ct.mrk.json"
        assert box.clear_landmarks_button.isEnabled()
        assert sorted(panel.landmark_table.column("landmark")) == sorted(THREE)
        assert panel.landmark_table.column("CT") == ["yes"] * 3
        wait_idle(qtbot, panel)
        assert session.preop_landmarks().ids == list(THREE)                              # saved with the nodes
        np.testing.assert_allclose(session.preop_landmarks().xyz, CT_LPS)
        assert session.preop_nodes().ids == box.nodes.ids
        box.threshold_slider.setValue(60)                                                # re-segmented: kept
        qtbot.waitUntil(lambda: not panel.busy and "0.60" in box.status.text(), timeout=TIMEOUT_MS)
        assert box.landmarks.ids == list(THREE) and box.status.text().endswith("; 3 landmarks from ct.mrk.json")
        wait_idle(qtbot, panel)
        assert session.preop_landmarks().ids == list(THREE) and len(session.preop_nodes()) == len(box.nodes)
        with qtbot.waitSignal(box.landmarks_changed, timeout=TIMEOUT_MS):
            qtbot.mouseClick(box.clear_landmarks_button, Qt.MouseButton.LeftButton)
        assert box.landmarks is None and not panel.landmark_table.isVisibleTo(panel)
        assert "landmark" not in box.status.text()
        wait_idle(qtbot, panel)
        assert len(session.preop_landmarks()) == 0


def test_a_node_file_with_its_own_landmarks_replaces_a_landmark_files_and_says_so(qtbot, panel, spect, tmp_path):
    box = panel.preop_box
    box.load_landmarks(slicer_points(tmp_path / "ct.mrk.json", THREE, CT_LPS, "LPS"))
    qtbot.waitUntil(lambda: not panel.busy and box.landmarks is not None, timeout=TIMEOUT_MS)
    assert box.status.text() == "no preop nodes: open a node file or a SPECT; 3 landmarks from ct.mrk.json"
    np.testing.assert_allclose(box.landmarks.xyz, CT_LPS)                                # LPS kept as it is
    write_nodes(NodeSet.from_xyz(SOURCES_LPS, [""] * 4, prefix="P"), tmp_path / "nodes.csv")   # no landmarks: kept
    panel.load_preop(tmp_path / "nodes.csv")
    qtbot.waitUntil(lambda: not panel.busy and box.nodes is not None, timeout=TIMEOUT_MS)
    assert box.status.text() == "4 nodes from nodes.csv; 3 landmarks from ct.mrk.json"
    own = NodeSet(list(THREE[:2]), ["", ""], CT_LPS[:2] + 1.0)
    write_nodes(NodeSet.from_xyz(SOURCES_LPS, [""] * 4, prefix="P"), tmp_path / "other.csv", landmarks=own)
    panel.load_preop(tmp_path / "other.csv")
    qtbot.waitUntil(lambda: not panel.busy and "other.csv" in box.status.text(), timeout=TIMEOUT_MS)
    assert box.landmarks.ids == list(THREE[:2])
    assert box.status.text() == "4 nodes and 2 landmarks from other.csv (replacing the 3 landmarks from ct.mrk.json)"


@pytest.mark.parametrize("content, said", [
    ("{not json", "not valid JSON"),
    ("id,label,x,y,z,kind\nP1,,1,2,3,node\n", "a landmark file holds landmarks only"),
    ("# frame: trocar\nid,label,x,y,z,kind\naortic bifurcation,,1,2,3,landmark\n", "in the trocar frame"),
])
def test_a_bad_landmark_file_is_one_sentence_and_loses_nothing(qtbot, panel, tmp_path, content, said):
    box = panel.preop_box
    write_nodes(NodeSet.from_xyz(SOURCES_LPS, [""] * 4, prefix="P"), tmp_path / "nodes.csv",
                landmarks=NodeSet(list(THREE), [""] * 3, CT_LPS))
    panel.load_preop(tmp_path / "nodes.csv")
    qtbot.waitUntil(lambda: not panel.busy and box.nodes is not None, timeout=TIMEOUT_MS)
    bad = tmp_path / ("bad.mrk.json" if content.startswith("{") else "bad.csv")
    bad.write_text(content)
    emitted = []
    box.landmarks_changed.connect(emitted.append)
    box.load_landmarks(bad)
    qtbot.waitUntil(lambda: not panel.busy and "reading" not in box.status.text(), timeout=TIMEOUT_MS)
    text = box.status.text()
    assert said in text and text.endswith(".") and text.count(". ") == 0 and "\n" not in text
    assert not emitted and box.landmarks.ids == list(THREE) and len(box.nodes) == 4        # nothing lost


def test_the_reading_rules_turn_ras_to_lps_and_refuse_other_frames_and_empty_files(tmp_path):
    csv_ras = tmp_path / "ras.csv"
    csv_ras.write_text("# frame: RAS\nid,label,x,y,z,kind\nAortic  Bifurcation,,10,-20,30,landmark\n")
    marks = read_preop_landmarks(csv_ras)
    assert marks.ids == ["aortic bifurcation"] and marks.frame == "LPS"       # name as snreg keeps it
    np.testing.assert_allclose(marks.xyz, [[-10.0, 20.0, 30.0]])
    plain = tmp_path / "plain.csv"
    plain.write_text("id,label,x,y,z,kind\naortic bifurcation,,10,-20,30,landmark\n")
    np.testing.assert_allclose(read_preop_landmarks(plain).xyz, [[10.0, -20.0, 30.0]])   # no frame: LPS
    empty = slicer_points(tmp_path / "empty.mrk.json", [], np.zeros((0, 3)), "RAS")
    with pytest.raises(NodeFileError, match="holds no landmarks"):
        read_preop_landmarks(empty)
    camera = tmp_path / "camera.csv"
    camera.write_text("# frame: camera\nid,label,x,y,z,kind\naortic bifurcation,,1,2,3,landmark\n")
    with pytest.raises(NodeFileError, match="in the camera frame; preop landmarks are placed on the CT"):
        read_preop_landmarks(camera)
