"""``snreg session info|export|recover`` through its own argparse parser."""

import argparse
import json

import numpy as np
import pytest

from snreg.cli.session import add_session_parser
from snreg.errors import UserError
from snreg.nodes import read_nodes
from snreg.session import Session
from snreg.session.journal import journal_path
from snreg.session.schema import FORMAT_VERSION


def _run(argv):
    parser = argparse.ArgumentParser(prog="snreg")
    add_session_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture
def session_file(tmp_path):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="phantom-01") as s:
        s.add_intraop_node("SN1", "OBT R", [1.0, 2.0, 3.0], counts=50.0)
        s.add_intraop_node("SN2", "EXT L", [4.0, 5.0, 6.5], counts=70.0)
        s.append_imu(np.arange(3), np.arange(3), np.zeros((3, 3)), np.zeros((3, 3)))
        s.log_event("store_refused", reason="the IMU is stale", trigger="F5")
    return path


def test_info_json(session_file, capsys):
    assert _run(["session", "info", str(session_file), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["case_id"] == "phantom-01" and info["intraop_nodes"] == 2
    assert info["streams"] == {"imu": 3, "probe": 0, "frames": 0, "camera": 0} and info["registrations"] == []
    assert info["format_version"] == FORMAT_VERSION and not info["damaged"] and info["events"] == {"store_refused": 1}


def test_info_text(session_file, capsys):
    _run(["session", "info", str(session_file)])
    out = capsys.readouterr().out
    assert "case phantom-01" in out and "2 intraop" in out


@pytest.mark.parametrize("fmt, name", [("csv", "nodes.csv"), ("slicer", "nodes.mrk.json")])
def test_export(session_file, tmp_path, fmt, name):
    out = tmp_path / name
    _run(["session", "export", str(session_file), "--format", fmt, "-o", str(out)])
    nodes = read_nodes(out)
    assert nodes.ids == ["SN1", "SN2"] and nodes.labels == ["OBT R", "EXT L"]
    np.testing.assert_allclose(nodes.xyz, [[1, 2, 3], [4, 5, 6.5]])
    if fmt == "csv":
        assert nodes.frame == "trocar" and list(nodes.counts) == [50.0, 70.0]


def test_recover_to_output(session_file, tmp_path):
    session_file.write_bytes(session_file.read_bytes()[:1500])
    out = tmp_path / "clean.h5"
    _run(["session", "recover", str(session_file), "-o", str(out)])
    with Session.open(out) as s:
        assert not s.damaged and s.intraop_nodes().ids == ["SN1", "SN2"]


@pytest.mark.parametrize("command", [["info"], ["export", "--format", "csv", "-o", "x.csv"], ["recover"]])
def test_bad_input_is_one_sentence(tmp_path, command):
    text = tmp_path / "notes.h5"
    text.write_text("not a session\n")
    with pytest.raises(UserError, match="not a readable snreg session|nothing to recover") as err:
        _run(["session", command[0], str(text), *command[1:]])
    assert "\n" not in str(err.value)
    assert text.read_text() == "not a session\n" and not journal_path(text).exists()
    with pytest.raises(UserError, match="no such session"):
        _run(["session", command[0], str(tmp_path / "none.h5"), *command[1:]])
