"""Damaged session files: read by a child first (a crash of libhdf5 is "damaged", never the end of the reader),
recovered without losing a readable row, whatever the root attributes say, and a journal checked line by line."""

import json
import os
import subprocess
import sys
import zlib

import h5py
import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.cli import main
from snreg.nodes import NodeSet
from snreg.registration import register
from snreg.session import Session, SessionError, opening
from snreg.session.filecheck import check_file
from snreg.session.journal import journal_path
from snreg.session.recovery import RecoverLock, recover

ROWS = {"imu": 3000, "probe": 700, "frames": 700, "camera": 700}      # imu: several chunks (1024 rows a chunk)
IDS = ["SN1", "SN2", "SN3", "SN4"]


def _session(path, rng):
    """Calibration, preop nodes, four nodes with snapshots, a registration and four streams."""
    xyz = np.array([[-55.0, 20, 30], [-45, 42, 8], [52, 18, 35], [12, 100, 72]])
    with Session.create(path, case_id="damage-01") as s:
        s.set_calibration(stereo=thesis_calibration(), chain=ChainCalibration.manual())
        s.set_preop_nodes(NodeSet.from_xyz(xyz, prefix="P", frame="LPS"))
        for k, node_id in enumerate(IDS):
            s.add_intraop_node(node_id, "OBT R", xyz[k] + 1.0, left_jpeg=b"\xff\xd8left", right_jpeg=b"\xff\xd8right")
        s.add_registration(register(xyz, xyz + 1.0, method="icp"), ["P1", "P2", "P3", "P4"], IDS)
        t = np.arange(ROWS["imu"], dtype=np.int64) * 4_807_692
        s.append_imu(t, t // 1000, rng.normal(size=(len(t), 3)), rng.normal(size=(len(t), 3)))
        n = ROWS["probe"]
        s.append_probe(t[:n], t[:n], rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), np.tile([0.0, 0, 1], (n, 1)),
                       np.full(n, 0.9))
        s.append_frames(t[:n], t[:n], np.arange(n))
        s.append_camera(t[:n], t[:n], rng.uniform(150, 170, n), "tracked", np.full(n, 0.9), np.zeros(n), np.zeros(n))


def _crash_root_format(path):
    """Flip the byte that crashes libhdf5 when the root attribute ``format`` is read (its datatype's class byte)."""
    data = bytearray(path.read_bytes())
    data[data.find(b"format\x00\x00") + 9] ^= 0xFF
    path.write_bytes(bytes(data))


def _rows(path) -> dict:
    with h5py.File(path, "r") as h5:
        return {name: h5[f"streams/{name}"].shape[0] for name in ROWS}


@pytest.fixture
def session(tmp_path, rng):
    path = tmp_path / "s.h5"
    _session(path, rng)
    return path


@pytest.mark.slow
def test_a_byte_that_crashes_libhdf5_makes_the_file_damaged_not_the_reader_dead(session, capsys):
    _crash_root_format(session)
    check = check_file(session)                   # the crash is real: the child reading the attribute was killed
    assert check.opens and "crashes libhdf5 (signal" in check.problems["/@format"]
    with Session.open(session) as s:
        assert s.damaged and s.intraop_nodes().ids == IDS and s.case_id == "damage-01"
        assert {name: len(s.stream(name)) for name in ROWS} == ROWS
        assert any("format is damaged" in p for p in s.problems)
    assert main(["session", "info", str(session)]) == 0       # in this process: it would die with a crash here
    assert "damaged: the root attribute format is damaged" in capsys.readouterr().out
    assert main(["session", "verify", str(session)]) == 1     # verify reads it in a child as well
    assert "DAMAGED attribute /@format: reading it crashes libhdf5 (signal" in capsys.readouterr().out
    assert main(["register", str(session), "--method", "icp", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)["nodes"]) == 4


def test_recover_keeps_every_readable_row_whatever_the_root_attributes_say(session):
    journal_path(session).unlink()
    with h5py.File(session, "r+") as h5:
        h5.attrs["format"] = "garbage"
    report = recover(session)
    assert not report.journal and report.backup is not None and report.nodes == (4, "file")
    assert report.streams == ROWS == _rows(session) == _rows(report.backup)
    text = "\n".join(report.lines())
    assert "there was no journal" in text and "imu 3000, probe 700, frames 700, camera 700 rows" in text
    with Session.open(session) as s:
        assert not s.damaged and s.intraop_nodes().ids == IDS and len(s.registrations()) == 1


@pytest.mark.slow
def test_two_recovers_at_once_keep_every_row_and_every_backup(session):
    _crash_root_format(session)
    with RecoverLock(session):                    # a recover under way: a second is refused, naming the first
        with pytest.raises(SessionError, match=rf"another recover is working on it \(process {os.getpid()} on "):
            recover(session)
    runs = [subprocess.Popen([sys.executable, "-m", "snreg.cli", "session", "recover", str(session)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outcomes = [(run.wait(120), *run.communicate()) for run in runs]
    assert all(code == 0 or (code == 2 and "another recover" in err) for code, _, err in outcomes), outcomes
    backups = sorted(session.parent.glob("s.h5.damaged-*"))
    assert len(backups) == sum(code == 0 for code, _, _ in outcomes) >= 1
    assert _rows(session) == ROWS and all(_rows(backup) == ROWS for backup in backups)
    recover(session)                               # again within the same second: a new name, no backup lost
    assert len(set(session.parent.glob("s.h5.damaged-*"))) == len(backups) + 1 and _rows(session) == ROWS


def test_a_cut_short_file_without_a_journal_is_read_up_to_the_cut(session):
    journal_path(session).unlink()
    with h5py.File(session, "r") as h5:                      # cut just after the IMU's first chunk: its rows survive
        first = h5["streams/imu"].id.get_chunk_info(0)
    session.write_bytes(session.read_bytes()[:first.byte_offset + first.size])
    with pytest.raises(SessionError, match="recover"):
        Session.open(session)
    report = recover(session)
    assert "cut short" in report.problems[0] and report.nodes[0] >= 1
    assert 1024 <= report.streams["imu"] < ROWS["imu"]


def _line(kind, data) -> bytes:
    payload = json.dumps({"kind": kind, "data": data}, separators=(",", ":")).encode()
    return b"%08x " % zlib.crc32(payload) + payload + b"\n"


def test_a_journal_line_with_a_good_checksum_and_a_bad_field_is_reported_and_left_out(session):
    with Session.open(session) as s:
        node = s.intraop_records()[0].to_json()
    lines = journal_path(session).read_bytes().count(b"\n")
    with open(journal_path(session), "ab") as journal:
        journal.write(_line("node", {k: v for k, v in {**node, "id": "SN9"}.items() if k != "label"}))
        journal.write(_line("node", {**node, "id": "SN8", "xyz_trocar": "here"}))
        journal.write(_line("registration", {"n": "seven"}))
        journal.write(_line("node", {**node, "id": "SN5"}))
    with Session.open(session) as s:
        assert s.intraop_nodes().ids == IDS + ["SN5"] and not s.damaged and len(s.registrations()) == 1
        assert s.problems[:3] == [f"journal line {lines + 1} (node) lacks 'label'; left out",
                                  f"journal line {lines + 2} (node) 'xyz_trocar' is not 3 numbers; left out",
                                  f"journal line {lines + 3} (registration) 'n' is text, not a whole number; left out"]


def test_a_video_record_naming_a_file_elsewhere_is_left_out(session):
    segment = {"n": 0, "files": ["../../etc/passwd", "s.right.mkv"], "first_row": 0, "fps": 30.0, "width": 1920,
               "height": 1080}
    with open(journal_path(session), "ab") as journal:
        journal.write(_line("video", segment))
        journal.write(_line("video", {**segment, "n": 1, "files": ["s.1.left.mkv", "s.1.right.mkv"]}))
    with Session.open(session) as s:
        assert [video.n for video in s.videos()] == [1]
        assert any("(video) 'files' is not two file names beside the session" in p for p in s.problems)


def test_without_a_journal_the_damage_is_said_plainly(session, capsys):
    journal_path(session).unlink()
    _crash_root_format(session)
    assert main(["session", "info", str(session)]) == 0
    assert "there is no journal beside it" in capsys.readouterr().out


def test_special_files_are_refused_in_one_sentence(tmp_path, session):
    fifo = tmp_path / "fifo.h5"
    os.mkfifo(fifo)
    with pytest.raises(SessionError, match="not a regular file"):
        Session.open(fifo)
    journal_path(session).unlink()
    os.mkfifo(journal_path(session))
    with pytest.raises(SessionError, match="journal: not a regular file"):
        Session.open(session)


def test_a_file_we_may_not_read_is_said_so_not_called_damaged(session, monkeypatch):
    monkeypatch.setattr(opening.os, "access", lambda path, mode: False)    # as for another user's file (not root)
    with pytest.raises(SessionError, match="no permission to read the session") as err:
        Session.open(session)
    assert "damaged" not in str(err.value) and "recover" not in str(err.value)
