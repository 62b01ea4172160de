"""The ``snreg`` command line: output contracts and one-line errors with exit status 2."""

import json
import subprocess
import sys

import numpy as np
import pytest

from snreg import geometry
from snreg.cli import main
from snreg.nodes import NodeSet, read_nodes, write_nodes


@pytest.fixture
def node_files(tmp_path, pelvic_nodes):
    xyz, labels = pelvic_nodes
    preop = NodeSet.from_xyz(xyz, labels, prefix="P")
    moved = geometry.apply(geometry.transform_from_euler(20, 10, -5, [10, -5, 12]), xyz)
    order = [3, 1, 0, 5, 4, 2]
    intraop = NodeSet(["SN1", "SN2", "SN3", "SN4", "SN5", "SN6"], [labels[k] for k in order], moved[order])
    write_nodes(preop, tmp_path / "preop.csv")
    write_nodes(intraop, tmp_path / "intraop.mrk.json")
    return tmp_path / "preop.csv", tmp_path / "intraop.mrk.json"


def test_register_writes_json(node_files, tmp_path, capsys):
    preop, intraop = node_files
    out = tmp_path / "result.json"
    assert main(["register", str(preop), str(intraop), "--labels", "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [n["preop_id"] for n in doc["nodes"]] == ["P4", "P2", "P1", "P6", "P5", "P3"]
    assert doc["rms_mm"] < 1e-6 and all(n["confident"] for n in doc["nodes"])
    assert np.asarray(doc["intraop_from_preop"]).shape == (4, 4)
    assert "RMS" in capsys.readouterr().out


def test_register_json_on_stdout(node_files, capsys):
    preop, intraop = node_files
    assert main(["register", str(preop), str(intraop), "--method", "icp", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["method"] == "icp" and len(doc["nodes"]) == 6


@pytest.mark.parametrize("content, fragment", [
    ("id,label,x,y,z\nA,,0,0,0\nB,,1,0,0\n", "at least 3 preop nodes"),
    ("garbage without header structure", "header lacks"),
])
def test_register_bad_input_is_one_line_exit_2(node_files, tmp_path, capsys, content, fragment):
    _, intraop = node_files
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    assert main(["register", str(bad), str(intraop)]) == 2
    err = capsys.readouterr().err
    assert fragment in err and err.count("\n") == 1


def test_register_reads_intraop_nodes_from_a_session(node_files, tmp_path, capsys, pelvic_nodes):
    from snreg.session import Session

    preop, _ = node_files
    xyz, labels = pelvic_nodes
    moved = geometry.apply(geometry.transform_from_euler(10, -5, 5, [4, 2, -3]), xyz)
    with Session.create(tmp_path / "s.h5", case_id="phantom-01") as session:
        for k in range(len(xyz)):
            session.add_intraop_node(f"SN{k + 1}", labels[k], moved[k])
    assert main(["register", str(preop), str(tmp_path / "s.h5"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [n["preop_id"] for n in doc["nodes"]] == [f"P{k + 1}" for k in range(len(xyz))]
    assert main(["register", str(preop), str(tmp_path / "missing.h5")]) == 2
    assert capsys.readouterr().err.count("\n") == 1


@pytest.mark.slow
def test_simulate_small(tmp_path):
    cmd = [sys.executable, "-m", "snreg.cli", "simulate", "--reps", "1", "--sigmas", "2,10", "--extras", "0,2",
           "--methods", "icp,global", "--workers", "1", "-o", str(tmp_path / "sim")]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "oracle NN" in done.stdout and "| 10 | 26 |" in done.stdout
    assert (tmp_path / "sim" / "report.md").exists() and (tmp_path / "sim" / "trials.csv").exists()
    assert "simulate: 26/26 patient x sigma blocks" in done.stderr


def test_simulate_rejects_bad_arguments(capsys):
    assert main(["simulate", "--methods", "global+magic"]) == 2
    assert "only +labels" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--sigmas", "two"])
    assert exc.value.code == 2


@pytest.mark.slow
def test_bench_prints_every_method(capsys):
    assert main(["bench", "--reps", "1", "--pairs", "3"]) == 0
    out = capsys.readouterr().out
    for method in ("icp", "cpd", "chamfer", "global"):
        assert f"| {method} | 52 |" in out
    assert "| triangulation | 3 |" in out and "| insertion (one core) | 3 |" in out


def test_experiment_imu_prints_the_protractor_table_and_drift(capsys):
    assert main(["experiment", "imu", "--seed", "1"]) == 0
    out = capsys.readouterr().out
    assert "| all |" in out and "horizontal plane (yaw) | 10 |" in out
    assert "deg/min with bias correction" in out


def test_preop_through_the_snreg_command_line(tmp_path, capsys):
    from snreg.demo.spect import THESIS_SOURCES, THESIS_VOXEL_MM, spect_of_nodes, write_nm
    from snreg.nodes import read_nodes

    counts, origin = spect_of_nodes(THESIS_SOURCES, seed=2)
    write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "phantom.dcm")
    assert main(["preop", str(tmp_path / "phantom.dcm"), "-o", str(tmp_path / "nodes.csv")]) == 0
    assert len(read_nodes(tmp_path / "nodes.csv")) == len(THESIS_SOURCES)
    (tmp_path / "text.dcm").write_text("not dicom")
    assert main(["preop", str(tmp_path / "text.dcm"), "-o", str(tmp_path / "x.csv")]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_register_takes_an_initial_alignment_file(node_files, tmp_path, capsys):
    preop, intraop = node_files
    rough = geometry.transform_from_euler(15, 8, -3, [8, -4, 10])
    (tmp_path / "initial.json").write_text(json.dumps({"transform": rough.tolist()}))
    assert main(["register", str(preop), str(intraop), "--initial", str(tmp_path / "initial.json"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["rms_mm"] < 1e-6
    (tmp_path / "bad.json").write_text(json.dumps([[1, 0], [0, 1]]))
    assert main(["register", str(preop), str(intraop), "--initial", str(tmp_path / "bad.json")]) == 2
    assert "must be 4x4" in capsys.readouterr().err


def _session_with_a_far_pose(path, pelvic_nodes):
    """A session whose intraop nodes are turned 120 degrees from the preop frame, with a registration that started
    from a rough alignment (as the app stores it)."""
    from snreg.registration import register
    from snreg.session import Session

    xyz, labels = pelvic_nodes
    far = geometry.transform_from_euler(120.0, 10.0, -5.0, [40.0, -20.0, 30.0])
    rough = far @ geometry.transform_from_euler(12.0, -6.0, 4.0, [6.0, 4.0, -3.0])
    preop = NodeSet.from_xyz(xyz, labels, prefix="P")
    with Session.create(path, case_id="phantom-02") as session:
        session.set_preop_nodes(preop)
        for k in [0, 1, 2, 4, 5]:                                  # P4 not found yet
            session.add_intraop_node(f"SN{k + 1}", labels[k], geometry.apply(far, xyz[k:k + 1])[0])
        intraop = session.intraop_nodes()
        session.add_registration(register(xyz, intraop.xyz, initial=rough), preop.ids, intraop.ids)
    return far


def test_register_a_session_alone_reuses_its_initial_alignment_and_names_missing_nodes(tmp_path, capsys, pelvic_nodes):
    far = _session_with_a_far_pose(tmp_path / "s.h5", pelvic_nodes)
    assert main(["register", str(tmp_path / "s.h5"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [n["preop_id"] for n in doc["nodes"]] == ["P1", "P2", "P3", "P5", "P6"]
    assert [m["preop_id"] for m in doc["missing"]] == ["P4"]
    expected = geometry.apply(far, pelvic_nodes[0][3:4])[0]
    assert np.linalg.norm(np.asarray(doc["missing"][0]["mapped_xyz"]) - expected) < 1e-3
    assert all(n["leave_one_out_mm"] is not None for n in doc["nodes"])
    # the exported files register the same way with --initial taken from the session
    assert main(["session", "export", str(tmp_path / "s.h5"), "--format", "csv", "-o", str(tmp_path / "nodes.csv")]) == 0
    capsys.readouterr()
    xyz, labels = pelvic_nodes
    preop_csv, intraop_csv = tmp_path / "preop.csv", tmp_path / "nodes.csv"
    write_nodes(NodeSet.from_xyz(xyz, labels, prefix="P"), preop_csv)
    assert main(["register", str(preop_csv), str(intraop_csv)]) == 2              # 120 degrees from identity
    assert "--initial" in capsys.readouterr().err
    assert main(["register", str(preop_csv), str(intraop_csv), "--initial", str(tmp_path / "s.h5"), "--json"]) == 0
    assert [n["preop_id"] for n in json.loads(capsys.readouterr().out)["nodes"]] == ["P1", "P2", "P3", "P5", "P6"]


def test_register_refuses_when_no_pairing_fits_the_bounds(tmp_path, capsys, pelvic_nodes):
    _session_with_a_far_pose(tmp_path / "s.h5", pelvic_nodes)
    (tmp_path / "identity.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    assert main(["register", str(tmp_path / "s.h5"), "--initial", str(tmp_path / "identity.txt")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--initial" in err and "--labels" in err and "--max-rotation" in err


def test_register_warns_of_a_far_or_extra_node(node_files, tmp_path, capsys):
    preop, intraop = node_files
    assert main(["register", str(preop), str(intraop), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []
    nodes = read_nodes(intraop)
    far = NodeSet(nodes.ids + ["SN7"], nodes.labels + [""], np.vstack([nodes.xyz, [[372.0, 0.0, 0.0]]]))
    write_nodes(far, tmp_path / "far.csv")
    assert main(["register", str(preop), str(tmp_path / "far.csv"), "--json"]) == 0
    warnings = json.loads(capsys.readouterr().out)["warnings"]
    assert len(warnings) == 1 and warnings[0].startswith("SN7 ")
    assert main(["register", str(preop), str(tmp_path / "far.csv")]) == 0
    assert f"warning: {warnings[0]}" in capsys.readouterr().out


def test_register_text_names_colliding_preop_ids_apart(node_files, tmp_path, capsys):
    """A preop file that also says SN1...: the text marks the preop side 'P:', the JSON keeps the file's ids."""
    preop, intraop = node_files
    renamed = read_nodes(preop)
    renamed.ids = [f"SN{k + 1}" for k in range(len(renamed))]
    write_nodes(renamed, tmp_path / "sn_preop.csv")
    assert main(["register", str(tmp_path / "sn_preop.csv"), str(intraop), "--labels"]) == 0
    out = capsys.readouterr().out
    assert "shown as P:<id>" in out and "SN1 -> P:SN4 " in out and "SN3 -> P:SN1 " in out
    assert main(["register", str(tmp_path / "sn_preop.csv"), str(intraop), "--labels", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["nodes"][0]["preop_id"] == "SN4"
    assert main(["register", str(preop), str(intraop), "--labels"]) == 0
    out = capsys.readouterr().out
    assert "SN1 -> P4 " in out and "P:" not in out
