"""``snreg preop`` through its own argparse parser: files, printed nodes, errors, privacy."""

import argparse
from pathlib import Path

import numpy as np
import pydicom
import pytest

from snreg.cli.preop import add_preop_parser
from snreg.demo.spect import THESIS_SOURCES, THESIS_VOXEL_MM, spect_of_nodes, write_nm
from snreg.errors import UserError
from snreg.nodes import read_nodes

DICOM_DIR = Path(__file__).resolve().parent / "data" / "dicom"
FAKE_NAME, FAKE_ID, FAKE_BIRTH = "Quaxlebrook^Zenobia", "PID-4471-QX", "19370415"


def run(*argv) -> int:
    parser = argparse.ArgumentParser(prog="snreg")
    add_preop_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["preop", *map(str, argv)])
    return args.func(args)


@pytest.fixture(scope="module")
def phantom(tmp_path_factory):
    counts, origin = spect_of_nodes(THESIS_SOURCES, seed=5)
    path = tmp_path_factory.mktemp("spect") / "phantom.dcm"
    write_nm(counts, origin, THESIS_VOXEL_MM, path, patient_name=FAKE_NAME, patient_id=FAKE_ID, birth_date=FAKE_BIRTH)
    return path


def test_writes_and_prints_the_nodes(phantom, tmp_path, capsys):
    assert run(phantom, "-o", tmp_path / "nodes.csv") == 0
    nodes = read_nodes(tmp_path / "nodes.csv")
    assert len(nodes) == 4 and nodes.frame == "LPS" and nodes.counts is not None
    assert np.abs(nodes.xyz[:, None] - THESIS_SOURCES[None]).sum(-1).min(axis=1).max() < 1.5
    out = capsys.readouterr().out
    assert "4 node(s)" in out and all(i in out for i in nodes.ids)


def test_stations_expected_count_and_threshold(phantom, tmp_path, capsys):
    table = tmp_path / "stations.csv"
    table.write_text("id,station\nP1,external iliac\nP2,OBT\n")
    run(phantom, "-o", tmp_path / "nodes.mrk.json", "--nodes", "2", "--threshold", "0.4", "--stations", table)
    nodes = read_nodes(tmp_path / "nodes.mrk.json")
    assert len(nodes) == 2 and nodes.labels[0].startswith("EXT ") and nodes.labels[1].startswith("OBT ")


def test_series_directory(tmp_path, capsys):
    counts, origin = spect_of_nodes(THESIS_SOURCES[:3], shape=(40, 64, 64), seed=6)
    write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "series", multiframe=False)
    run(tmp_path / "series", "-o", tmp_path / "nodes.csv")
    assert len(read_nodes(tmp_path / "nodes.csv")) == 3


def test_no_patient_identity_reaches_any_output(phantom, tmp_path, capsys):
    run(phantom, "-o", tmp_path / "nodes.csv")
    run(phantom, "-o", tmp_path / "nodes.mrk.json", "--nodes", "3")
    ds = pydicom.dcmread(phantom)
    ds.DetectorInformationSequence[0].ImageOrientationPatient = None     # geometry lost: warning path
    ds.save_as(tmp_path / "placed.dcm")
    run(tmp_path / "placed.dcm", "-o", tmp_path / "placed.csv")
    captured = capsys.readouterr()
    texts = [captured.out, captured.err] + [p.read_text() for p in tmp_path.glob("*") if p.suffix != ".dcm"]
    assert "placed with identity orientation" in captured.err
    for secret in ("Quaxlebrook", "Zenobia", FAKE_ID, FAKE_BIRTH, "1937"):
        assert not any(secret.lower() in text.lower() for text in texts), secret


def test_real_heart_sample_warns_and_marks_the_node_file(tmp_path, capsys):
    run(DICOM_DIR / "NM-MONO2-16-13x-heart.dcm", "-o", tmp_path / "heart.csv", "--nodes", "1")
    assert "no patient position/orientation" in capsys.readouterr().err
    nodes = read_nodes(tmp_path / "heart.csv")
    assert len(nodes) == 1 and any("placed by default" in c for c in nodes.comments)


def test_undecodable_jpeg_sample_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="cannot be decoded"):
        run(DICOM_DIR / "NM1_JPLY.dcm", "-o", tmp_path / "nodes.csv")


def test_bad_input_is_a_user_error(phantom, tmp_path):
    (tmp_path / "x.txt").write_text("hello")
    ct = pydicom.dcmread(phantom)
    ct.Modality = "CT"
    ct.save_as(tmp_path / "ct.dcm")
    (tmp_path / "bad_stations.csv").write_text("id,station\nP1,kidney\n")
    (tmp_path / "old_stations.csv").write_text("id,station\nSN1,OBT\n")
    cases = [((tmp_path / "x.txt",), "not a readable DICOM"),
             ((tmp_path / "ct.dcm",), "modality CT, not NM"),
             ((phantom, "--threshold", "1.2"), "between 0 and 1"),
             ((phantom, "--stations", tmp_path / "bad_stations.csv"), "not a known station"),
             ((phantom, "--stations", tmp_path / "missing.csv"), "no such station table file"),
             ((phantom, "--stations", tmp_path / "old_stations.csv"), "names SN1, but the nodes found are P1")]
    for argv, message in cases:
        with pytest.raises(UserError, match=message):
            run(*argv, "-o", tmp_path / "nodes.csv")
    assert not (tmp_path / "nodes.csv").exists()
