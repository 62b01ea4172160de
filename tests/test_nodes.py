import json
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snreg.nodes import NodeFileError, NodeSet, read_nodes, write_nodes


def make_nodes(counts=True):
    return NodeSet(["SN1", "SN2", "SN3"], ["OBT R", "", "EXT L"],
                   np.array([[1.5, -2.25, 300.0], [0.0, 1e-3, -12.5], [123456.7, 8.0, 9.0]]),
                   np.array([120.0, 3.5, 0.0]) if counts else None, frame="trocar")


def test_csv_round_trip_keeps_everything(tmp_path):
    nodes = make_nodes()
    write_nodes(nodes, tmp_path / "n.csv")
    text = (tmp_path / "n.csv").read_text()
    assert text.startswith("# frame: trocar\nid,label,x,y,z,counts\n")
    back = read_nodes(tmp_path / "n.csv")
    assert back.ids == nodes.ids and back.labels == nodes.labels and back.frame == "trocar"
    np.testing.assert_allclose(back.xyz, nodes.xyz, atol=1e-6)
    np.testing.assert_allclose(back.counts, nodes.counts)


def test_csv_without_counts_and_with_comments(tmp_path):
    path = tmp_path / "n.csv"
    path.write_text("# exported by hand\nid,label,x,y,z\n# a comment between rows\nA,OBT R,1,2,3\nB,,4,5,6\n\n")
    nodes = read_nodes(path)
    assert nodes.ids == ["A", "B"] and nodes.labels == ["OBT R", ""] and nodes.counts is None
    assert nodes.comments == ["exported by hand", "a comment between rows"]


def test_csv_columns_may_come_in_any_order(tmp_path):
    path = tmp_path / "n.csv"
    path.write_text("x,y,z,label,id\n1,2,3,INT L,N1\n")
    nodes = read_nodes(path)
    assert nodes.ids == ["N1"] and nodes.labels == ["INT L"]
    np.testing.assert_allclose(nodes.xyz, [[1, 2, 3]])


def test_slicer_round_trip(tmp_path):
    nodes = make_nodes(counts=False)
    write_nodes(nodes, tmp_path / "n.mrk.json")
    doc = json.loads((tmp_path / "n.mrk.json").read_text())
    assert doc["markups"][0]["type"] == "Fiducial" and doc["markups"][0]["coordinateSystem"] == "LPS"
    back = read_nodes(tmp_path / "n.mrk.json")
    assert back.ids == nodes.ids and back.labels == nodes.labels
    np.testing.assert_allclose(back.xyz, nodes.xyz)


def test_slicer_ras_file_is_converted_to_lps(tmp_path):
    doc = {"markups": [{"type": "Fiducial", "coordinateSystem": "RAS",
                        "controlPoints": [{"id": "1", "label": "F-1", "position": [10.0, 20.0, 30.0]}]}]}
    (tmp_path / "r.mrk.json").write_text(json.dumps(doc))
    np.testing.assert_allclose(read_nodes(tmp_path / "r.mrk.json").xyz, [[-10.0, -20.0, 30.0]])


@pytest.mark.parametrize("content, message", [
    ("", "no header"),
    ("name,x,y,z\nA,1,2,3\n", "header lacks id, label"),
    ("id,label,x,y,z\nA,OBT R,1,two,3\n", "not a number"),
    ("id,label,x,y,z\nA,OBT R,1,2\n", "has 4 fields"),
    ("id,label,x,y,z\nA,,1,2,3\nA,,4,5,6\n", "unique"),
    ("id,label,x,y,z\nA,,1,nan,3\n", "finite"),
])
def test_bad_csv_gives_a_clear_error(tmp_path, content, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(NodeFileError, match=message) as err:
        read_nodes(path)
    assert str(path) in str(err.value)


def test_foreign_files_give_a_clear_error(tmp_path):
    (tmp_path / "x.mrk.json").write_text('{"something": 1}')
    with pytest.raises(NodeFileError, match="not a 3D Slicer fiducial list"):
        read_nodes(tmp_path / "x.mrk.json")
    (tmp_path / "bin.csv").write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(NodeFileError, match="not a text node file"):
        read_nodes(tmp_path / "bin.csv")
    with pytest.raises(NodeFileError, match="no such node file"):
        read_nodes(tmp_path / "missing.csv")


def test_special_files_are_not_read(tmp_path):
    os.mkfifo(tmp_path / "fifo.csv")                 # a pipe would block the reader, /dev/zero never end
    for path in (tmp_path / "fifo.csv", Path("/dev/zero"), Path("/dev/null")):
        with pytest.raises(NodeFileError, match="not a regular file"):
            read_nodes(path)
    (tmp_path / "folder.csv").mkdir()
    with pytest.raises(NodeFileError, match="is a folder"):
        read_nodes(tmp_path / "folder.csv")


@pytest.mark.parametrize("name, content, message", [
    ("semicolon.csv", "id;label;x;y;z\nP1;a;1;2;3\n", "separated by semicolons: node files are comma-separated"),
    ("tab.csv", "id\tlabel\tx\ty\tz\nP1\ta\t1\t2\t3\n", "separated by tabs"),
    ("field.csv", "id,label,x,y,z\nP1," + "A" * 140_000 + ",1,2,3\n", "not a readable CSV"),
    ("huge.csv", "id,label,x,y,z\nP1,a," + "9" * 400 + ",2,3\n", "must be finite"),
    ("deep.mrk.json", "[" * 100_000 + "]" * 100_000, "nested too deeply"),
    ("huge.mrk.json", '{"markups":[{"controlPoints":[{"position":[' + "9" * 400 + ',0,0]}]}]}', "too large for mm"),
    ("digits.mrk.json", '{"markups":[{"controlPoints":[{"position":[' + "9" * 5000 + ',0,0]}]}]}', "not valid JSON"),
])
def test_hostile_node_files_are_refused_in_one_sentence(tmp_path, name, content, message):
    (tmp_path / name).write_text(content)
    with pytest.raises(NodeFileError, match=message) as err:
        read_nodes(tmp_path / name)
    assert "\n" not in str(err.value)


label_text = st.text(alphabet=st.characters(blacklist_categories=("Cs", "Cc")), max_size=12).map(str.strip)
coordinate = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(label_text, coordinate, coordinate, coordinate), min_size=1, max_size=8))
def test_csv_round_trip_property(tmp_path_factory, rows):
    nodes = NodeSet([f"N{k}" for k in range(len(rows))], [r[0] for r in rows], np.array([r[1:] for r in rows]))
    path = tmp_path_factory.mktemp("p") / "n.csv"
    write_nodes(nodes, path)
    back = read_nodes(path)
    assert back.labels == nodes.labels
    np.testing.assert_allclose(back.xyz, nodes.xyz, atol=1e-6)
