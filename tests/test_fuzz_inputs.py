"""Fuzzing every reader of outside input (hypothesis, seeded and derandomized, a few seconds each): node files,
calibration files, DICOM headers, the journal, and sessions with flipped bytes beside an intact journal. Whatever
the bytes, a reader returns what it read or raises its own one-sentence error, never anything else; and nothing a
journal recorded is lost to damage in the HDF5 file. (The IMU line protocol's fuzzing is in test_imu_protocol.py.)"""

import json
import zlib

import numpy as np
import pydicom
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from snreg.camera import THESIS_CALIBRATION_PATH, CalibrationFileError, load_calibration
from snreg.demo.spect import write_nm
from snreg.errors import NodeFileError, PreopError, SessionError
from snreg.nodes import read_nodes
from snreg.preop import load_volume, segment_nodes
from snreg.session import Session
from snreg.session.journal import journal_path
from snreg.session.recovery import recover

def fuzz(examples: int) -> settings:
    return settings(max_examples=examples, derandomize=True, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])

# pieces hostile input is made of: separators, quotes, numbers far out of range, deep nesting, control bytes
PIECES = st.sampled_from(["id,label,x,y,z", "P1", "OBT R", ",", ";", "\t", '"', "\n", "\r\n", "#", "1", "-2.5", "nan",
                          "inf", "1e400", "9" * 400, "\x00", "\ufeff", "[", "]", "{", "}", '"markups"', ":",
                          '"controlPoints"', '"position"', "[1,2,3]", "null", "[" * 3000, "A" * 140000])


@fuzz(120)
@given(parts=st.lists(PIECES, max_size=40), suffix=st.sampled_from([".csv", ".mrk.json"]))
def test_node_files_are_read_or_refused_in_one_sentence(tmp_path_factory, parts, suffix):
    path = tmp_path_factory.mktemp("nodes") / f"n{suffix}"
    path.write_text("".join(parts), encoding="utf-8", errors="surrogatepass")
    try:
        nodes = read_nodes(path)
    except NodeFileError as err:
        assert "\n" not in str(err) and str(path) in str(err)
        return
    assert np.all(np.isfinite(nodes.xyz)) and len(set(nodes.ids)) == len(nodes)


THESIS_TEXT = THESIS_CALIBRATION_PATH.read_text()
TOKENS = ["1e400", "-1e200", ".Nan", ".Inf", "0.", "[", "]", "{", "}", "rows: 3", "cols: 9", "dt: q", "!!opencv-matrix",
          '"abc"', "\n", "   ", ":", "-", "image_width: 1000000000", "data: [ 0. ]", "%YAML:1.0", "a: " + "[" * 200]


@fuzz(100)
@given(cuts=st.lists(st.tuples(st.integers(0, len(THESIS_TEXT)), st.integers(0, 40), st.sampled_from(TOKENS + [""])),
                     min_size=1, max_size=4))
@pytest.mark.slow
def test_calibration_files_are_read_or_refused_in_one_sentence(tmp_path_factory, cuts):
    text = THESIS_TEXT
    for at, remove, token in cuts:             # cut something out, put a hostile token in its place
        text = text[:at] + token + text[at + remove:]
    path = tmp_path_factory.mktemp("calib") / "c.yaml"
    path.write_text(text)
    try:
        calib = load_calibration(path)
    except CalibrationFileError as err:
        assert "\n" not in str(err)
        return
    assert calib.image_size[0] >= 1 and np.all(np.isfinite(calib.Q)) and calib.baseline_mm > 0


NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6),
                    st.sampled_from(["abc", "", "1e999", "-0"]))
HEADER = {"ImageOrientationPatient": st.lists(NUMBERS, max_size=8), "ImagePositionPatient": st.lists(NUMBERS, max_size=5),
          "PixelSpacing": st.lists(NUMBERS, max_size=3), "SliceThickness": NUMBERS, "SpacingBetweenSlices": NUMBERS,
          "RescaleSlope": NUMBERS, "RescaleIntercept": NUMBERS, "NumberOfFrames": st.integers(-5, 10**6),
          "Rows": st.integers(0, 70000), "Columns": st.integers(0, 70000), "BitsAllocated": st.sampled_from([1, 7, 8, 16, 32, 64])}


@pytest.fixture(scope="module")
def small_spect(tmp_path_factory):
    counts = np.full((6, 16, 16), 2.0)
    counts[2:4, 6:9, 6:9] = 900.0
    path = tmp_path_factory.mktemp("spect") / "nm.dcm"
    write_nm(counts, np.zeros(3), 4.0, path)
    return path


def _set(ds, name, value):
    where = ds.DetectorInformationSequence[0] if name in ("ImageOrientationPatient", "ImagePositionPatient") else ds
    text = "\\".join(str(v) for v in value) if isinstance(value, list) else str(value)
    if name in where:
        del where[name]
    vr = {"NumberOfFrames": "IS", "Rows": "US", "Columns": "US", "BitsAllocated": "US"}.get(name, "LO")
    where.add_new(pydicom.datadict.tag_for_keyword(name), vr, value if vr == "US" else text)


@fuzz(80)
@given(changes=st.lists(st.sampled_from(sorted(HEADER)).flatmap(lambda k: st.tuples(st.just(k), HEADER[k])),
                        min_size=1, max_size=4))
def test_dicom_headers_are_read_or_refused_in_one_sentence(small_spect, tmp_path_factory, changes):
    ds = pydicom.dcmread(small_spect)
    for name, value in changes:
        _set(ds, name, value)
    path = tmp_path_factory.mktemp("dcm") / "nm.dcm"
    try:
        ds.save_as(path, enforce_file_format=False)
    except Exception:                                              # pydicom cannot even write it: nothing to read
        return
    try:
        volume = load_volume(path, modality="NM")
        segment_nodes(volume, threshold=0.3)
    except PreopError as err:
        assert "\n" not in str(err)


def _line(kind, data) -> bytes:
    payload = json.dumps({"kind": kind, "data": data}, separators=(",", ":")).encode()
    return b"%08x " % zlib.crc32(payload) + payload + b"\n"


JSON = st.recursive(st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
                    max_leaves=12)
KINDS = st.sampled_from(["session", "node", "node_removed", "event", "nodes_reexpressed", "calibration", "preop",
                         "registration", "final", "other"])
# good entries of each kind, of which the fuzzing spoils a field or two (a value of another type, or none)
TEMPLATES = {
    "node": {"id": "SN7", "label": "OBT R", "time_ns": 5, "xyz_trocar": [1.0, 2.0, 3.0], "xyz_camera": [1.0, 2.0, 3.0],
             "spread_mm": 0.5, "n_frames": 30, "counts": 1.0, "left_jpeg": "ffd8", "right_jpeg": "",
             "earth_from_imu": np.eye(3).tolist(), "stereo_version": "", "chain_version": ""},
    "registration": {"n": 0, "method": "icp", "rms_mm": 1.0, "pairing_rule": "nearest", "transform": np.eye(4).tolist(),
                     "pairing": [0, 1, 2], "distances_mm": [1.0, 1.0, 1.0], "confidence": [1.0, 1.0, 1.0],
                     "preop_ids": ["P1", "P2", "P3"], "intraop_ids": ["SN1", "SN2", "SN7"]},
    "preop": {"ids": ["P1", "P2", "P3"], "labels": ["", "", ""], "xyz": np.eye(3).tolist(), "counts": None, "frame": "LPS"},
    "nodes_reexpressed": {"n": 1, "kind": "nodes_reexpressed", "nodes": [
        {"id": "SN1", "xyz_trocar": [0.0, 0.0, 1.0], "xyz_camera": [0.0, 0.0, 1.0], "stereo_version": "",
         "chain_version": ""}]},
    "final": {"n": 0}, "node_removed": {"id": "SN7"}, "event": {"n": 3, "kind": "store_refused"},
}
SPOILED = st.sampled_from(sorted(TEMPLATES)).flatmap(lambda kind: st.tuples(
    st.just(kind), st.dictionaries(st.sampled_from(sorted(TEMPLATES[kind])), JSON | st.just(None), max_size=2),
    st.lists(st.sampled_from(sorted(TEMPLATES[kind])), max_size=1)).map(
        lambda t: (t[0], {k: v for k, v in {**TEMPLATES[t[0]], **t[1]}.items() if k not in t[2]})))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A small session with two nodes, streams and a journal; its bytes and the journal's."""
    path = tmp_path_factory.mktemp("recorded") / "s.h5"
    with Session.create(path, case_id="fuzz-01") as s:
        for k in range(2):
            s.add_intraop_node(f"SN{k + 1}", "EXT L", [k, 2.0, 3.0], left_jpeg=b"\xff\xd8", right_jpeg=b"")
        t = np.arange(2500, dtype=np.int64)
        s.append_imu(t, t, np.zeros((2500, 3)), np.zeros((2500, 3)))
        s.log_event("acquisition_started")
    return path.read_bytes(), journal_path(path).read_bytes()


@pytest.mark.slow
@fuzz(150)
@given(entries=st.lists(st.tuples(KINDS, JSON) | SPOILED, max_size=6), noise=st.binary(max_size=80))
def test_journal_lines_of_any_content_never_stop_the_reader(recorded, tmp_path_factory, entries, noise):
    path = tmp_path_factory.mktemp("journal") / "s.h5"              # the journal alone: it is what is fuzzed here
    journal_path(path).write_bytes(recorded[1] + b"".join(_line(kind, data) for kind, data in entries) + noise + b"\n")
    with Session.open(path) as s:
        ids = set(s.intraop_nodes().ids)           # every entry that reads is checked: nothing raises past here
        s.registrations(), s.calibration(), s.preop_nodes(), s.events()
    assert {"SN1", "SN2"} <= ids or any(kind in ("node_removed", "nodes_reexpressed") for kind, _ in entries)


@pytest.mark.slow
@fuzz(12)
@given(position=st.floats(0, 1), xor=st.integers(1, 255), near_start=st.booleans())
def test_a_flipped_byte_beside_an_intact_journal_loses_no_stored_node(recorded, tmp_path_factory, position, xor,
                                                                       near_start):
    data = bytearray(recorded[0])
    span = min(len(data), 40_000) if near_start else len(data)      # the metadata is mostly near the start
    data[int(position * (span - 1))] ^= xor
    folder = tmp_path_factory.mktemp("flipped")
    path = folder / "s.h5"
    path.write_bytes(bytes(data))
    journal_path(path).write_bytes(recorded[1])
    with Session.open(path) as s:
        assert s.intraop_nodes().ids == ["SN1", "SN2"] and s.case_id == "fuzz-01"
    report = recover(path, folder / "clean.h5")
    with Session.open(report.path) as s:
        assert s.intraop_nodes().ids == ["SN1", "SN2"] and not s.damaged


def test_a_session_that_is_not_one_is_refused_in_one_sentence(tmp_path):
    path = tmp_path / "s.h5"
    path.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 40)
    with pytest.raises(SessionError) as err:
        Session.open(path)
    assert "\n" not in str(err.value)
