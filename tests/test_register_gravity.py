"""``snreg register`` and the app's run start from gravity (issue 30): the SPECT's patient position turned by the table
tilt, the IMU's down through the session's chain; the options override, bad input is refused in one line."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg import geometry
from snreg.chain import ChainCalibration
from snreg.cli import main
from snreg.demo.spect import THESIS_VOXEL_MM, spect_of_nodes, write_nm
from snreg.nodes import NodeSet, write_nodes
from snreg.preop.gravity import PreopDown
from snreg.session import Session, SessionError
from snreg.session.schema import calibration_version
from snreg.workflow.registration_run import RunRequest, run_registration
from snreg.workflow.registration_start import session_gravity

TRUE_TILT_DEG = 26.0                   # the table as it was; the team enters snreg's default, 30
IMU_AT_REFERENCE = Rotation.from_euler("ZYX", [0.0, 8.0, -95.0], degrees=True).as_matrix()


def far_pose(preop_down, intraop_down, heading_deg, shift):
    """(4, 4) intraop_from_preop: the downs aligned, then turned ``heading_deg`` about gravity, shifted far."""
    turn = (Rotation.from_rotvec(np.radians(heading_deg) * intraop_down)
            * Rotation.align_vectors(intraop_down[None], preop_down[None])[0])
    return geometry.make_transform(turn.as_matrix(), shift)


def make_session(path, xyz, labels, *, heading_deg=140.0, seed=0, chain=True, preop_down=None, other_chain=False):
    """A session of the nodes stored in the trocar frame of a chain referenced at ``IMU_AT_REFERENCE``, the patient
    supine on a table tilted ``TRUE_TILT_DEG`` head down, any heading, 250 mm away; 2 mm of noise. Returns the truth."""
    reference = ChainCalibration.manual().with_reference(IMU_AT_REFERENCE)
    truth = far_pose(PreopDown("HFS", TRUE_TILT_DEG).vector, reference.down_trocar, heading_deg, [250.0, -90.0, 120.0])
    intraop = geometry.apply(truth, xyz) + np.random.default_rng(seed).normal(0.0, 2.0, xyz.shape)
    version = "0badc0de" if other_chain else calibration_version(reference.to_dict())
    with Session.create(path, case_id="gravity-01") as session:
        if chain:
            session.set_calibration(chain=reference)
        if preop_down is not None:
            session.set_preop_nodes(NodeSet.from_xyz(xyz, labels, prefix="P", frame="LPS"), down=preop_down)
        for k, point in enumerate(intraop):
            session.add_intraop_node(f"SN{k + 1}", labels[k], point, chain_version=version)
    return truth


def preop_csv(path, xyz, labels, down: PreopDown | None = PreopDown("HFS")):
    """The preop nodes as snreg preop writes them: LPS, the patient position and tilt in the comments."""
    nodes = NodeSet.from_xyz(xyz, labels, prefix="P", frame="LPS", comments=[] if down is None else down.comments())
    write_nodes(nodes, path)
    return path


def run(capsys, *argv):
    try:
        status = main(["register", *map(str, argv)])
    except SystemExit as exit_:                          # argparse's refusal of an option's value
        status = exit_.code
    out, err = capsys.readouterr()
    return status, out, err


def test_a_spect_and_a_session_register_from_gravity_with_no_angle_typed(tmp_path, capsys, pelvic_nodes):
    xyz, labels = pelvic_nodes
    counts, origin = spect_of_nodes(xyz, centre=xyz.mean(axis=0), seed=5)
    write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "spect.dcm")                  # Patient Position HFS
    assert main(["preop", str(tmp_path / "spect.dcm"), "-o", str(tmp_path / "p.csv"), "--nodes", "6"]) == 0
    assert "down: 0.000, 0.866, 0.500 (LPS), DICOM HFS (supine, head first)" in capsys.readouterr().out
    truth = make_session(tmp_path / "s.h5", xyz, labels)
    status, out, _ = run(capsys, tmp_path / "p.csv", tmp_path / "s.h5")
    assert status == 0
    assert "start: gravity, table tilt 30 deg head down (default), heading searched" in out
    assert "gravity at the endoscope (trocar frame):" in out
    assert "as the IMU on the endoscope measures it, through the trocar calibration" in out
    assert "chain's reference" not in out and "intraop (trocar)" not in out      # no internal terms (issue 35)
    status, out, _ = run(capsys, tmp_path / "p.csv", tmp_path / "s.h5", "--json")
    doc = json.loads(out)
    assert doc["start"]["kind"] == "gravity"
    np.testing.assert_allclose(doc["start"]["down_preop"], [0.0, np.cos(np.pi / 6), 0.5], atol=1e-12)
    preop = {n.split(",")[0]: np.array(n.split(",")[2:5], float)
             for n in (tmp_path / "p.csv").read_text().splitlines() if n.startswith("P")}
    for node in doc["nodes"]:                           # each stored node paired with the hot spot it came from
        k = int(node["id"][2:]) - 1
        assert np.linalg.norm(preop[node["preop_id"]] - xyz[k]) < 3.0
    moved = geometry.apply(np.array(doc["intraop_from_preop"]), xyz)
    assert np.sqrt(np.mean(np.sum((moved - geometry.apply(truth, xyz)) ** 2, axis=1))) < 4.0
    # the same files from the identity (as before gravity) are out of reach
    (tmp_path / "identity.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    assert run(capsys, tmp_path / "p.csv", tmp_path / "s.h5", "--initial", tmp_path / "identity.txt")[0] == 2


def test_a_session_alone_keeps_its_preop_down_and_registers_from_gravity(tmp_path, capsys, pelvic_nodes):
    xyz, labels = pelvic_nodes
    make_session(tmp_path / "s.h5", xyz, labels, heading_deg=-70.0, preop_down=PreopDown("HFS", 28.0, True))
    with Session.open(tmp_path / "s.h5") as session:
        assert session.preop_down() == PreopDown("HFS", 28.0, True)
        start = session_gravity(session)
    assert start.words == "start: gravity, table tilt 28 deg head down (entered), heading searched"
    status, out, _ = run(capsys, tmp_path / "s.h5", "--json")
    doc = json.loads(out)
    assert status == 0 and doc["start"]["kind"] == "gravity"
    assert [n["preop_id"] for n in doc["nodes"]] == [f"P{k + 1}" for k in range(6)]


def test_the_options_override_what_the_files_say(tmp_path, capsys, pelvic_nodes):
    xyz, labels = pelvic_nodes
    truth = make_session(tmp_path / "s.h5", xyz, labels)
    preop_csv(tmp_path / "p.csv", xyz, labels)
    status, out, _ = run(capsys, tmp_path / "p.csv", tmp_path / "s.h5", "--tilt", "20", "--json")
    start = json.loads(out)["start"]
    assert status == 0 and start["words"] == "start: gravity, table tilt 20 deg head down (entered), heading searched"
    np.testing.assert_allclose(start["down_preop"], [0.0, np.cos(np.radians(20)), np.sin(np.radians(20))], atol=1e-12)
    # an intraop node file carries no down: from the identity it fails and says what to give; with the down it pairs
    assert main(["session", "export", str(tmp_path / "s.h5"), "--format", "csv", "-o", str(tmp_path / "i.csv")]) == 0
    capsys.readouterr()
    status, _, err = run(capsys, tmp_path / "p.csv", tmp_path / "i.csv")
    assert status == 2 and "--down-intraop" in err and err.count("\n") == 1
    down = ",".join(f"{v:.6f}" for v in ChainCalibration.manual().with_reference(IMU_AT_REFERENCE).down_trocar * 3)
    status, out, _ = run(capsys, tmp_path / "p.csv", tmp_path / "i.csv", f"--down-intraop={down}", "--json")
    doc = json.loads(out)
    assert status == 0 and doc["start"]["intraop_source"] == "given with --down-intraop"
    assert [n["preop_id"] for n in doc["nodes"]] == [f"P{k + 1}" for k in range(6)]
    # a node file from elsewhere (no patient position) with both downs given
    preop_csv(tmp_path / "plain.csv", xyz, labels, down=None)
    true_preop_down = truth[:3, :3].T @ ChainCalibration.manual().with_reference(IMU_AT_REFERENCE).down_trocar
    given = ",".join(f"{v:.6f}" for v in true_preop_down)
    status, out, _ = run(capsys, tmp_path / "plain.csv", tmp_path / "s.h5", f"--down-preop={given}", "--json")
    doc = json.loads(out)
    assert status == 0 and doc["start"]["preop_source"] == "given with --down-preop"
    assert doc["start"]["words"] == "start: gravity, the preop down given, heading searched"
    # --initial still overrides, as before
    np.savetxt(tmp_path / "truth.txt", truth)
    status, out, _ = run(capsys, tmp_path / "p.csv", tmp_path / "s.h5", "--initial", tmp_path / "truth.txt")
    assert status == 0 and f"start: the initial alignment of {tmp_path / 'truth.txt'}" in out


def test_without_any_down_the_start_is_as_before_and_says_why(tmp_path, capsys, pelvic_nodes):
    xyz, labels = pelvic_nodes
    preop_csv(tmp_path / "p.csv", xyz, labels, down=None)
    write_nodes(NodeSet.from_xyz(geometry.apply(geometry.transform_from_euler(20, 10, -5, [10, -5, 12]), xyz), labels),
                tmp_path / "i.csv")
    status, out, _ = run(capsys, tmp_path / "p.csv", tmp_path / "i.csv", "--json")
    start = json.loads(out)["start"]
    assert status == 0 and start["kind"] == "identity"
    assert "records no patient position" in start["words"]


@pytest.mark.parametrize("options, words", [
    (["--down-preop", "0,0,0"], "--down-preop: expected a direction X,Y,Z pointing down"),
    (["--down-intraop", "nan,0,1"], "--down-intraop: expected finite numbers"),
    (["--down-preop", "0,1"], "three finite numbers"),
    (["--tilt", "61"], "--tilt: expected a number from 0 to 60 degrees"),
    (["--tilt", "-5"], "--tilt: expected a number from 0 to 60 degrees"),
    (["--tilt", "20", "--initial", "{s.h5}"], "--initial gives the start, --tilt gravity's"),
    (["--tilt", "20", "--down-preop", "0,1,0"], "drop --tilt"),
])
def test_bad_downs_and_tilts_are_refused_in_one_line(tmp_path, capsys, pelvic_nodes, options, words):
    xyz, labels = pelvic_nodes
    make_session(tmp_path / "s.h5", xyz, labels)
    preop_csv(tmp_path / "p.csv", xyz, labels)
    status, _, err = run(capsys, tmp_path / "p.csv", tmp_path / "s.h5",
                         *[o.replace("{s.h5}", str(tmp_path / "s.h5")) for o in options])
    assert status == 2 and words in err and err.count("\n") == 1


@pytest.mark.parametrize("position, words", [("", "no usable patient position"), ("HFDL", "on their side")])
def test_a_spect_without_a_usable_patient_position_is_refused_saying_what_to_do(tmp_path, capsys, pelvic_nodes,
                                                                                  position, words):
    xyz, labels = pelvic_nodes
    make_session(tmp_path / "s.h5", xyz, labels)
    preop_csv(tmp_path / "p.csv", xyz, labels, down=PreopDown(position))
    for extra in ([], ["--tilt", "25"]):
        status, _, err = run(capsys, tmp_path / "p.csv", tmp_path / "s.h5", *extra)
        assert status == 2 and err.count("\n") == 1
        assert words in err and "--down-preop X,Y,Z" in err and "--initial" in err


def test_a_down_asked_for_but_unknown_is_refused(tmp_path, capsys, pelvic_nodes):
    xyz, labels = pelvic_nodes
    make_session(tmp_path / "nochain.h5", xyz, labels, chain=False)
    make_session(tmp_path / "mixed.h5", xyz, labels, other_chain=True)
    preop_csv(tmp_path / "p.csv", xyz, labels)
    preop_csv(tmp_path / "plain.csv", xyz, labels, down=None)
    status, _, err = run(capsys, tmp_path / "p.csv", tmp_path / "nochain.h5", "--tilt", "30")
    assert status == 2 and "holds no chain calibration" in err and "--down-intraop" in err
    status, _, err = run(capsys, tmp_path / "plain.csv", tmp_path / "nochain.h5", "--tilt", "30")
    assert status == 2 and "plain.csv records no patient position" in err and "--down-preop" in err
    status, out, _ = run(capsys, tmp_path / "p.csv", tmp_path / "mixed.h5", "--json", "--max-rotation", "180",
                         "--max-translation", "400")
    assert status == 0 and "mapped with chain 0badc0de" in json.loads(out)["start"]["words"]
    with Session.open(tmp_path / "nochain.h5") as session, pytest.raises(SessionError, match="no chain calibration"):
        session_gravity(session, PreopDown("HFS"))


def test_the_apps_run_starts_from_gravity_and_says_so(tmp_path, pelvic_nodes):
    xyz, labels = pelvic_nodes
    make_session(tmp_path / "s.h5", xyz, labels, heading_deg=200.0)
    preop = NodeSet.from_xyz(xyz, labels, prefix="P", frame="LPS")
    with Session.resume(tmp_path / "s.h5") as session:
        gravity = session_gravity(session, PreopDown("HFS"))
        request = RunRequest(preop, session.intraop_nodes(), "global", False, np.eye(4), 60.0, 60.0, session=session,
                             gravity=gravity, preop_down=PreopDown("HFS"))
        record = run_registration(request)
    assert record.stored and record.start == "start: gravity, table tilt 30 deg head down (default), heading searched"
    np.testing.assert_array_equal(record.result.pairing, np.arange(6))           # the typed identity ignored
    with Session.open(tmp_path / "s.h5") as session:
        assert session.preop_down() == PreopDown("HFS")
        assert session.registrations()[-1].result.pairing.tolist() == list(range(6))
    typed = run_registration(RunRequest(preop, record.intraop, "global", False, record.result.transform, 60.0, 60.0))
    assert typed.start == "start: the initial alignment entered"


def test_a_tilt_far_from_the_tables_finds_no_fit_and_says_what_to_check(tmp_path, capsys, pelvic_nodes):
    xyz, labels = pelvic_nodes
    make_session(tmp_path / "s.h5", xyz, labels)
    preop_csv(tmp_path / "p.csv", xyz, labels, down=PreopDown("HFP"))           # prone: the down upside down
    status, _, err = run(capsys, tmp_path / "p.csv", tmp_path / "s.h5")
    assert status == 2 and err.count("\n") == 1
    assert "gravity's start" in err and "--tilt" in err and "--initial" in err


def test_the_preop_down_is_kept_through_every_copy_of_the_session_and_checked_in_the_journal(tmp_path, pelvic_nodes):
    from snreg.session.entries import EntryError, check_entry

    xyz, labels = pelvic_nodes
    make_session(tmp_path / "s.h5", xyz, labels, preop_down=PreopDown("FFS", 35.0, True))
    with Session.open(tmp_path / "s.h5") as session:
        session.save_as(tmp_path / "copy.h5")
    with Session.open(tmp_path / "copy.h5") as copy:
        assert copy.preop_down() == PreopDown("FFS", 35.0, True)
    with Session.resume(tmp_path / "s.h5") as session:                  # a new preop set without one: unknown
        session.set_preop_nodes(NodeSet.from_xyz(xyz, labels, prefix="P"))
    with Session.open(tmp_path / "s.h5") as session:
        assert session.preop_down() is None
    entry = {"ids": ["P1"], "labels": [""], "xyz": [[0.0, 0.0, 0.0]], "frame": "LPS",
             "down": {"patient_position": "HFS", "table_tilt_deg": 90.0, "tilt_entered": True}}
    with pytest.raises(EntryError, match="'down' is not a patient position with a table tilt"):
        check_entry("preop", entry)
    assert check_entry("preop", {**entry, "down": None})["down"] is None
