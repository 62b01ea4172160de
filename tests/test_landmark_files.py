"""Anatomical landmarks in node files (snreg.nodes, snreg.landmarks): a CSV's ``kind`` column and 3D Slicer markups in
RAS or LPS read into the same landmarks, kept apart from the nodes; names as one rule keeps them; refusals in one
sentence."""

import json

import numpy as np
import pytest

from snreg.landmarks import LANDMARKS, in_vocabulary, landmark_name
from snreg.nodes import NodeFile, NodeFileError, NodeSet, read_landmarks, read_node_file, read_nodes, write_nodes

SEED = 2929
NAMES = ["aortic bifurcation", "right common iliac bifurcation", "left common iliac bifurcation"]


@pytest.fixture(scope="module")
def truth():
    """Three landmarks and two nodes in patient LPS, mm (seeded)."""
    rng = np.random.default_rng(SEED)
    return rng.uniform(-120, 120, (3, 3)).round(3), rng.uniform(-120, 120, (2, 3)).round(3)


def slicer_doc(system: str, lists: list[tuple[str, list[str], np.ndarray]]) -> dict:
    """A markups document as 3D Slicer writes it: each (list name, labels, LPS positions) as a fiducial list in
    ``system`` (the list name left out when empty, as Slicer itself does)."""
    flip = np.array([-1.0, -1.0, 1.0]) if system == "RAS" else np.ones(3)
    markups = []
    for name, labels, xyz in lists:
        points = [{"id": str(k + 1), "label": label, "description": "", "position": list(xyz[k] * flip),
                   "positionStatus": "defined"} for k, label in enumerate(labels)]
        markups.append({"type": "Fiducial", **({"name": name} if name else {}), "coordinateSystem": system,
                        "coordinateUnits": "mm", "controlPoints": points})
    return {"@schema": "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/"
                       "Schema/markups-schema-v1.0.3.json#", "markups": markups}


def test_a_csv_kind_column_keeps_landmarks_apart_from_the_nodes(tmp_path, truth):
    marks, nodes = truth
    rows = [f"P1,OBT R,{','.join(map(str, nodes[0]))},120,", f"P2,,{','.join(map(str, nodes[1]))},80,node"]
    rows += [f"{name.title()},CT,{','.join(map(str, xyz))},,landmark" for name, xyz in zip(NAMES, marks)]
    (tmp_path / "preop.csv").write_text("# frame: LPS\nid,label,x,y,z,counts,kind\n" + "\n".join(rows) + "\n")
    read = read_node_file(tmp_path / "preop.csv")
    assert read.nodes.ids == ["P1", "P2"] and list(read.nodes.counts) == [120.0, 80.0]
    assert read.landmarks.ids == NAMES                       # the vocabulary's spelling, whatever the case typed
    assert read.landmarks.labels == ["CT"] * 3 and read.landmarks.counts is None and read.landmarks.frame == "LPS"
    np.testing.assert_allclose(read.landmarks.xyz, marks)
    assert read_nodes(tmp_path / "preop.csv").ids == ["P1", "P2"]        # never a landmark among the nodes
    write_nodes(read.nodes, tmp_path / "again.csv", landmarks=read.landmarks)
    text = (tmp_path / "again.csv").read_text()
    assert "id,label,x,y,z,counts,kind\n" in text and "aortic bifurcation,CT," in text
    assert text.count(",landmark\n") == 3
    back = read_node_file(tmp_path / "again.csv")
    assert back.nodes.ids == read.nodes.ids and back.landmarks.ids == read.landmarks.ids
    np.testing.assert_allclose(back.landmarks.xyz, marks)


def test_a_file_without_landmarks_is_written_as_before(tmp_path, truth):
    nodes = NodeSet(["P1", "P2"], ["", ""], truth[1], frame="LPS")
    write_nodes(nodes, tmp_path / "n.csv")
    assert (tmp_path / "n.csv").read_text().splitlines()[1] == "id,label,x,y,z"
    write_nodes(nodes, tmp_path / "n.mrk.json")
    assert len(json.loads((tmp_path / "n.mrk.json").read_text())["markups"]) == 1


@pytest.mark.parametrize("system", ["RAS", "LPS"])
def test_markups_in_ras_and_in_lps_give_the_csvs_landmarks(tmp_path, truth, system):
    marks, nodes = truth
    csv = NodeFile(NodeSet(["P1", "P2"], ["", ""], nodes), NodeSet(NAMES, [""] * 3, marks))
    (tmp_path / "p.csv").write_text(csv.to_csv())
    expected = read_node_file(tmp_path / "p.csv")
    # one point list holding nodes and vocabulary-labelled landmarks, as a radiologist may place them
    mixed = slicer_doc(system, [("", ["P1", NAMES[0].upper(), "P2", *NAMES[1:]], np.vstack([nodes[0], marks[0],
                                                                                              nodes[1], marks[1:]]))])
    # a list named for landmarks (snreg's own export), any names in it
    named = slicer_doc(system, [("", ["P1", "P2"], nodes), ("CT landmarks", NAMES, marks)])
    for k, doc in enumerate((mixed, named)):
        (tmp_path / f"{k}.mrk.json").write_text(json.dumps(doc))
        read = read_node_file(tmp_path / f"{k}.mrk.json")
        assert read.nodes.ids == ["P1", "P2"] and sorted(read.landmarks.ids) == sorted(expected.landmarks.ids)
        order = [read.landmarks.ids.index(name) for name in expected.landmarks.ids]
        np.testing.assert_allclose(read.landmarks.xyz[order], expected.landmarks.xyz, atol=1e-9)     # LPS
        np.testing.assert_allclose(read.nodes.xyz, expected.nodes.xyz, atol=1e-9)
    # a point list saved on its own (Slicer writes one list per file): every point a landmark, whatever its name
    (tmp_path / "alone.mrk.json").write_text(json.dumps(slicer_doc(system, [("", ["left ureter crossing"],
                                                                            marks[:1])])))
    alone = read_landmarks(tmp_path / "alone.mrk.json")
    assert alone.ids == ["left ureter crossing"]
    np.testing.assert_allclose(alone.xyz, marks[:1], atol=1e-9)
    assert read_nodes(tmp_path / "alone.mrk.json").ids == ["left ureter crossing"]   # read as nodes, it is a node


def test_snreg_markups_round_trip_with_a_landmark_list(tmp_path, truth):
    marks, nodes = truth
    write_nodes(NodeSet(["P1", "P2"], ["OBT R", ""], nodes), tmp_path / "p.mrk.json",
                landmarks=NodeSet(["sacral promontory", NAMES[0]], ["", ""], marks[:2]))
    doc = json.loads((tmp_path / "p.mrk.json").read_text())
    assert [m.get("name") for m in doc["markups"]] == [None, "landmarks"]
    assert all(m["coordinateSystem"] == "LPS" for m in doc["markups"])
    read = read_node_file(tmp_path / "p.mrk.json")
    assert read.nodes.ids == ["P1", "P2"] and read.landmarks.ids == ["sacral promontory", NAMES[0]]
    np.testing.assert_allclose(read.landmarks.xyz, marks[:2])


def test_one_rule_keeps_every_landmark_name():
    assert landmark_name("  Aortic   BIFURCATION ") == "aortic bifurcation"
    assert landmark_name("left ureter  crossing") == "left ureter crossing"
    assert in_vocabulary("Top of the pubic symphysis") and not in_vocabulary("P1")
    assert set(LANDMARKS) == {landmark_name(name.upper()) for name in LANDMARKS}


@pytest.mark.parametrize("name, content, message", [
    ("twice.csv", "id,label,x,y,z,kind\naortic bifurcation,,1,2,3,landmark\nAortic Bifurcation,,4,5,6,landmark\n",
     "landmark 'aortic bifurcation' is given twice; give each landmark once"),
    ("empty.csv", "id,label,x,y,z,kind\n ,,1,2,3,landmark\n", "has an empty id; every node needs a unique id"),
    ("id.csv", "id,label,x,y,z,kind\nSN2,,1,2,3,landmark\n", "'SN2' looks like a node id, not a landmark name"),
    ("kind.csv", "id,label,x,y,z,kind\nX,,1,2,3,vessel\n", "kind 'vessel' is neither 'node' nor 'landmark'"),
    ("both.csv", "id,label,x,y,z,kind\nX,,1,2,3,landmark\nX,,1,2,3,node\n", "ids must be unique; repeated: X"),
    ("long.csv", "id,label,x,y,z,kind\n" + "a" * 80 + ",,1,2,3,landmark\n", "is 80 characters long; keep it to 64"),
    ("unnamed.mrk.json", json.dumps(slicer_doc("LPS", [("landmarks", [""], np.zeros((1, 3)))])),
     r"control point 1 \(1\): a landmark needs a name"),
])
def test_bad_landmarks_are_refused_in_one_sentence(tmp_path, name, content, message):
    (tmp_path / name).write_text(content)
    with pytest.raises(NodeFileError, match=message) as err:
        read_node_file(tmp_path / name)
    assert str(tmp_path / name) in str(err.value) and "\n" not in str(err.value)


def test_a_landmark_file_with_nodes_in_it_is_refused(tmp_path):
    (tmp_path / "l.csv").write_text("id,label,x,y,z,kind\nP1,,1,2,3,node\naortic bifurcation,,1,2,3,\n")
    with pytest.raises(NodeFileError, match="P1 is a node \\(kind node\\); a landmark file holds landmarks only"):
        read_landmarks(tmp_path / "l.csv")
