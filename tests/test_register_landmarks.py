"""``snreg register`` with anatomical landmarks: one SN plus three landmarks from files (a CSV's kind column, Slicer
markups in RAS, a landmark file of its own, a session), each pair's residuals and the suspects in words and JSON."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.cli import main
from snreg.nodes import NodeSet, write_nodes
from snreg.session import Session

SEED = 2931
NAMES = ["aortic bifurcation", "right common iliac bifurcation", "left common iliac bifurcation"]
PREOP_MARKS = np.array([[0.0, 85.0, 160.0], [-40.0, 80.0, 95.0], [40.0, 80.0, 95.0]])      # LPS, mm
PREOP = np.array([[10.0, 20.0, 30.0], [-35.0, 45.0, 60.0]])
TURN = Rotation.from_euler("ZYX", [20, 5, -5], degrees=True).as_matrix()


def surgery(xyz, rng, sd_mm):
    """Where points of the preop frame lie in the intraop frame, with ``sd_mm`` of error per axis."""
    return np.asarray(xyz) @ TURN.T + [5.0, -10.0, 3.0] + rng.normal(0.0, sd_mm, np.shape(xyz))


@pytest.fixture
def files(tmp_path):
    """preop.csv (two nodes, three landmarks by kind), intraop.mrk.json (SN1 and the landmarks in RAS, vocabulary
    labels in the same point list), swapped.mrk.json (two landmark names exchanged)."""
    rng = np.random.default_rng(SEED)
    write_nodes(NodeSet(["P1", "P2"], ["OBT R", ""], PREOP, frame="LPS"), tmp_path / "preop.csv",
                landmarks=NodeSet(NAMES, ["", "", ""], PREOP_MARKS, frame="LPS"))
    sn1, marks = surgery(PREOP[:1], rng, 1.0), surgery(PREOP_MARKS, rng, 1.0)
    for name, labels in (("intraop", ["SN1", *NAMES]), ("swapped", ["SN1", NAMES[1], NAMES[0], NAMES[2]])):
        points = [{"id": str(k), "label": label, "position": list(xyz * [-1, -1, 1])}
                  for k, (label, xyz) in enumerate(zip(labels, np.vstack([sn1, marks])))]
        doc = {"markups": [{"type": "Fiducial", "coordinateSystem": "RAS", "controlPoints": points}]}
        (tmp_path / f"{name}.mrk.json").write_text(json.dumps(doc))
    return tmp_path


def test_one_sn_and_three_landmarks_from_files_register(files, capsys):
    assert main(["register", str(files / "preop.csv"), str(files / "intraop.mrk.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [(n["id"], n["preop_id"]) for n in doc["nodes"]] == [("SN1", "P1")]
    assert [row["name"] for row in doc["landmarks"]] == sorted(NAMES) and doc["landmarks_suspect"] == []
    assert all(row["residual_mm"] < 5.0 and not row["suspect"] for row in doc["landmarks"])
    assert doc["landmark_sd_mm"] == 2.0 and doc["landmarks_unpaired"] == {"preop": [], "intraop": []}
    assert main(["register", str(files / "preop.csv"), str(files / "intraop.mrk.json")]) == 0
    out = capsys.readouterr().out
    assert "SN1 -> P1" in out and "landmarks: 3 pairs, each with 2 mm of its own error per axis" in out
    assert "aortic bifurcation" in out and "SUSPECT" not in out


def test_a_swapped_name_is_named_suspect(files, capsys):
    assert main(["register", str(files / "preop.csv"), str(files / "swapped.mrk.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    [suspect] = doc["landmarks_suspect"]
    assert suspect in NAMES[:2] and [row["name"] for row in doc["landmarks"] if row["suspect"]] == [suspect]
    assert any(f"landmark {suspect!r} contradicts the nodes and the other landmarks" in w for w in doc["warnings"])
    assert main(["register", str(files / "preop.csv"), str(files / "swapped.mrk.json")]) == 0
    out = capsys.readouterr().out
    assert "SUSPECT: left out of the fit" in out and f"warning: landmark {suspect!r} contradicts" in out


def test_landmarks_from_a_file_of_their_own_and_unpaired_ones_said(files, capsys):
    write_nodes(NodeSet(["P1", "P2"], ["", ""], PREOP, frame="LPS"), files / "nodes.csv")
    (files / "ct.mrk.json").write_text(json.dumps({"markups": [{"type": "Fiducial", "coordinateSystem": "LPS",
        "controlPoints": [{"label": name, "position": list(xyz)} for name, xyz in
                          zip([*NAMES, "sacral promontory"], [*PREOP_MARKS, [0.0, 100.0, 60.0]])]}]}))
    assert main(["register", str(files / "nodes.csv"), str(files / "intraop.mrk.json"), "--preop-landmarks",
                 str(files / "ct.mrk.json"), "--landmark-sd", "3", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["landmarks"]) == 3 and doc["landmark_sd_mm"] == 3.0
    assert doc["landmarks_unpaired"] == {"preop": ["sacral promontory"], "intraop": []}
    assert "landmark 'sacral promontory' is on the CT only: touch it with the probe" in " ".join(doc["warnings"])
    assert main(["register", str(files / "preop.csv"), str(files / "intraop.mrk.json"), "--preop-landmarks",
                 str(files / "ct.mrk.json")]) == 2
    assert "landmark 'aortic bifurcation' is in the node file too; give each landmark once" in capsys.readouterr().err


def test_preop_landmarks_in_another_frame_are_refused_as_the_app_refuses_them(files, capsys):
    write_nodes(NodeSet(["P1", "P2"], ["", ""], PREOP, frame="LPS"), files / "nodes.csv")
    (files / "touched.csv").write_text("# frame: trocar\nid,label,x,y,z,kind\n" + "".join(
        f"{name},,{x},{y},{z},landmark\n" for name, (x, y, z) in zip(NAMES, PREOP_MARKS)))
    assert main(["register", str(files / "nodes.csv"), str(files / "intraop.mrk.json"), "--preop-landmarks",
                 str(files / "touched.csv")]) == 2
    assert "its points are in the trocar frame; preop landmarks are placed on the CT" in capsys.readouterr().err

def test_a_session_registers_with_its_landmarks(tmp_path, capsys):
    rng = np.random.default_rng(SEED)
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="lm-cli") as session:
        session.set_preop_nodes(NodeSet(["P1", "P2"], ["", ""], PREOP, frame="LPS"),
                                NodeSet(NAMES, ["", "", ""], PREOP_MARKS, frame="LPS"))
        session.add_intraop_node("SN1", "", surgery(PREOP[0], rng, 1.0))
        for name, xyz in zip(NAMES, surgery(PREOP_MARKS, rng, 1.0)):
            session.add_intraop_node(name, "", xyz, kind="landmark")
    assert main(["register", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [n["preop_id"] for n in doc["nodes"]] == ["P1"] and len(doc["landmarks"]) == 3


def test_one_sn_without_landmarks_is_refused_naming_them(files, capsys):
    write_nodes(NodeSet(["SN1"], [""], PREOP[:1]), files / "one.csv")
    assert main(["register", str(files / "preop.csv"), str(files / "one.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "landmark" in err
