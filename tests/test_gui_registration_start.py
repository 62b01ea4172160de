"""The registration panel's start (issue 30), through its real widgets offscreen: gravity by default (the preop down
from the SPECT's patient position or a node file's comments and the table tilt, the intraop down from the session's
chain), the typed angles as an override, a fallback said in one sentence when gravity is unknown, the tilt's range,
and the down saved with the preop nodes with the tilt's source. Seeded synthetic sessions, compared to the truth."""

import numpy as np
import pytest
from PySide6.QtCore import Qt
from scipy.spatial.transform import Rotation

from snreg import geometry
from snreg.chain import ChainCalibration
from snreg.cli import main
from snreg.demo.spect import THESIS_VOXEL_MM, spect_of_nodes, write_nm
from snreg.errors import PreopError
from snreg.nodes import NodeSet, write_nodes
from snreg.preop.gravity import PreopDown
from snreg.session import Session
from snreg_gui.registration.panel import RegistrationPanel
from snreg_gui.registration.start import OVERRIDE_WORDS

TIMEOUT_MS = 15_000
TRUE_TILT_DEG = 26.0                    # the table as it was; the panel assumes snreg's default, 30
IMU_AT_REFERENCE = Rotation.from_euler("ZYX", [0.0, 8.0, -95.0], degrees=True).as_matrix()
GRAVITY_DEFAULT = "start: gravity, table tilt 30 deg head down (default), heading searched"


def far_case(path, xyz, labels, *, heading_deg=140.0, seed=3, chain=True, stored_down=None):
    """A writable session at ``path``: the nodes stored in the trocar frame of a chain referenced at
    ``IMU_AT_REFERENCE`` (none when ``chain`` is False), the patient supine on a table tilted ``TRUE_TILT_DEG`` head
    down, turned ``heading_deg`` about gravity and 250 mm away (out of reach of the centroids matched), 1.5 mm of noise
    (shuffled). Returns the open session and the truth (preop index per intraop node)."""
    reference = ChainCalibration.manual().with_reference(IMU_AT_REFERENCE)
    down_preop, down_trocar = PreopDown("HFS", TRUE_TILT_DEG).vector, reference.down_trocar
    turn = (Rotation.from_rotvec(np.radians(heading_deg) * down_trocar)
            * Rotation.align_vectors(down_trocar[None], down_preop[None])[0])
    truth = geometry.make_transform(turn.as_matrix(), [250.0, -90.0, 120.0])
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(xyz))
    intraop = geometry.apply(truth, xyz)[order] + rng.normal(0.0, 1.5, xyz.shape)
    session = Session.create(path, case_id="gui-start-01")
    if chain:
        session.set_calibration(chain=reference)
    if stored_down is not None:
        session.set_preop_nodes(NodeSet.from_xyz(xyz, labels, prefix="P", frame="LPS"), down=stored_down)
    for k, point in enumerate(intraop):
        session.add_intraop_node(f"SN{k + 1}", labels[order[k]], point)
    return session, order


def load_preop_csv(qtbot, panel, path, xyz, labels, down: PreopDown | None = PreopDown("HFS")):
    """The preop nodes as ``snreg preop`` writes them (LPS, the patient position and tilt in the comments; none when
    ``down`` is None), loaded through the panel."""
    nodes = NodeSet.from_xyz(xyz, labels, prefix="P", frame="LPS", comments=[] if down is None else down.comments())
    write_nodes(nodes, path)
    panel.load_preop(path)
    qtbot.waitUntil(lambda: not panel.busy and panel.preop_box.nodes is not None, timeout=TIMEOUT_MS)


def click_run(qtbot, panel):
    with qtbot.waitSignal(panel.registered, timeout=TIMEOUT_MS) as blocker:
        qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    return blocker.args[0]


def type_into(qtbot, spin, text: str) -> None:
    """The operator clicks into a spin box, types ``text`` over its value and presses Enter."""
    spin.setFocus()
    spin.lineEdit().selectAll()
    qtbot.keyClicks(spin.lineEdit(), text)
    qtbot.keyClick(spin.lineEdit(), Qt.Key.Key_Return)


def test_gravity_is_the_default_start_and_the_result_says_so(qtbot, panel, pelvic_nodes, tmp_path):
    xyz, labels = pelvic_nodes
    session, truth = far_case(tmp_path / "case.h5", xyz, labels)
    with session:
        panel.set_session(session)
        load_preop_csv(qtbot, panel, tmp_path / "p.csv", xyz, labels)
        assert panel.start_box.use_gravity and panel.start_box.tilt_spin.value() == 30.0
        assert panel.start_box.status.text() == f"Next run's {GRAVITY_DEFAULT}."
        result = click_run(qtbot, panel)
        assert np.array_equal(result.pairing, truth) and result.rms_mm < 4.0
        assert GRAVITY_DEFAULT in panel.summary.text().splitlines()
        assert panel.message.text() == "Stored in the session as registration 0."
        # the same nodes from the typed alignment (centroids matched, no turn) are out of reach: gravity did it
        panel.start_box.typed_radio.setChecked(True)
        qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
        assert "no pairing" in panel.message.text().lower()


def test_touching_the_typed_angles_overrides_gravity_and_says_so(qtbot, panel, pelvic_nodes, tmp_path):
    xyz, labels = pelvic_nodes
    session, _ = far_case(tmp_path / "case.h5", xyz, labels)
    with session:
        panel.set_session(session)
        load_preop_csv(qtbot, panel, tmp_path / "p.csv", xyz, labels)
        panel.alignment.set_values((10.0, 0.0, 0.0))            # set by the program (e.g. a reset): no override
        panel.alignment.reset()
        assert panel.start_box.use_gravity
        panel.show()
        qtbot.waitExposed(panel)
        type_into(qtbot, panel.alignment.angle_spins["yaw"], "20")
        assert panel.alignment.angles_deg[0] == 20.0
        assert panel.start_box.typed_radio.isChecked() and not panel.start_box.use_gravity
        assert panel.start_box.status.text().startswith("Your typed angles override gravity")
        qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
        # this far case is out of reach of the typed start: the run is refused, and says so; a reachable one shows it
        assert "no pairing" in panel.message.text().lower()
    intraop = NodeSet.from_xyz(geometry.apply(geometry.make_transform(geometry.rotation_from_euler(20.0, 0, 0),
                                                                      [30.0, 0.0, 0.0]), xyz), labels, prefix="I")
    panel.set_session(None)
    panel.set_intraop_nodes(intraop)
    result = click_run(qtbot, panel)
    assert np.array_equal(result.pairing, np.arange(len(xyz)))
    assert OVERRIDE_WORDS in panel.summary.text().splitlines()


def test_a_preop_without_a_patient_position_falls_back_with_a_sentence(qtbot, panel, pelvic_nodes, tmp_path):
    xyz, labels = pelvic_nodes
    # reachable from the centroids matched: no turn about gravity, only the 22 degrees between the two downs
    session, truth = far_case(tmp_path / "case.h5", xyz, labels, heading_deg=0.0)
    with session:
        panel.set_session(session)
        load_preop_csv(qtbot, panel, tmp_path / "plain.csv", xyz, labels, down=None)
        assert panel.preop_box.down is None and panel.start_box.use_gravity      # still chosen, not usable
        status = panel.start_box.status.text()
        assert status == ("Gravity cannot give the start: the preop nodes carry no patient position (a SPECT without "
                          "one, or a node file not written from a SPECT by snreg preop); the typed alignment is used "
                          "(centroids matched, or the angles you type).")
        result = click_run(qtbot, panel)
        assert np.array_equal(result.pairing, truth)
        start = [line for line in panel.summary.text().splitlines() if line.startswith("start:")]
        assert start == ["start: the typed initial alignment (not gravity: the preop nodes carry no patient position "
                         "(a SPECT without one, or a node file not written from a SPECT by snreg preop))"]


def test_every_reason_gravity_is_unknown_is_said(qtbot, panel, pelvic_nodes, tmp_path):
    xyz, labels = pelvic_nodes
    status = panel.start_box.status
    load_preop_csv(qtbot, panel, tmp_path / "p.csv", xyz, labels)
    assert "no session is open" in status.text()
    session, _ = far_case(tmp_path / "nochain.h5", xyz, labels, chain=False)
    with session:
        panel.set_session(session)
        assert "the session holds no chain calibration" in status.text() and str(tmp_path) not in status.text()
        panel.set_intraop_nodes(session.intraop_nodes())               # a node file opened beside the session
        assert "the intraop nodes come from a node file, which carries no down" in status.text()
    # a SPECT of a patient on their side (read in the worker that loads it) gives no down either
    counts, origin = spect_of_nodes(xyz, centre=xyz.mean(axis=0), seed=5)
    session, _ = far_case(tmp_path / "side.h5", xyz, labels)
    with session:
        panel.set_session(session)
        panel.load_preop(write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "side.dcm", patient_position="HFDR")[0])
        qtbot.waitUntil(lambda: not panel.busy and panel.preop_box.down is not None, timeout=TIMEOUT_MS)
        assert panel.preop_box.down.patient_position == "HFDR"
        assert status.text().startswith("Gravity cannot give the start: the SPECT was taken with the patient on their "
                                        "side (Patient Position HFDR)")
        panel.load_preop(write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "hfs.dcm")[0])     # supine: gravity
        qtbot.waitUntil(lambda: not panel.busy and panel.preop_box.down.patient_position == "HFS", timeout=TIMEOUT_MS)
        assert status.text().startswith("Next run's start: gravity, table tilt 30 deg head down (default)")
        qtbot.waitUntil(lambda: session.preop_down() == PreopDown("HFS"), timeout=TIMEOUT_MS)


def test_a_tilt_outside_0_to_60_degrees_is_refused(qtbot, panel):
    spin = panel.start_box.tilt_spin
    assert (spin.minimum(), spin.maximum(), spin.value(), spin.suffix()) == (0.0, 60.0, 30.0, " deg")
    panel.show()
    qtbot.waitExposed(panel)
    type_into(qtbot, spin, "75")                         # the box takes no more than 60
    assert spin.value() <= 60.0
    spin.setValue(-5.0)
    assert spin.value() == 0.0
    for tilt in (75.0, -5.0, float("nan")):
        with pytest.raises(PreopError, match="the table tilt must be 0 to 60 degrees head down"):
            PreopDown("HFS", tilt)


@pytest.mark.slow
def test_the_down_is_saved_in_the_session_with_the_tilts_source(qtbot, panel, pelvic_nodes, tmp_path, capsys):
    xyz, labels = pelvic_nodes
    session, truth = far_case(tmp_path / "case.h5", xyz, labels)
    with session:
        panel.set_session(session)
        load_preop_csv(qtbot, panel, tmp_path / "p.csv", xyz, labels)
        qtbot.waitUntil(lambda: session.preop_down() == PreopDown("HFS", 30.0, False), timeout=TIMEOUT_MS)
        assert not panel.start_box.tilt_entered
        panel.show()
        qtbot.waitExposed(panel)
        type_into(qtbot, panel.start_box.tilt_spin, "26")         # the team's table as it really is
        qtbot.waitUntil(lambda: not panel.busy and session.preop_down() == PreopDown("HFS", 26.0, True),
                        timeout=TIMEOUT_MS)
        assert panel.start_box.status.text() == "Next run's start: gravity, table tilt 26 deg head down (entered), " \
                                                "heading searched."
        result = click_run(qtbot, panel)
        assert np.array_equal(result.pairing, truth)
        assert "start: gravity, table tilt 26 deg head down (entered), heading searched" in panel.summary.text()
    with Session.open(tmp_path / "case.h5") as stored:
        assert stored.preop_down() == PreopDown("HFS", 26.0, True)
        other = RegistrationPanel()                                # opened again: the entered tilt is shown
        qtbot.addWidget(other)
        other.set_session(stored)
        assert other.start_box.tilt_spin.value() == 26.0 and other.start_box.tilt_entered
        assert other.preop_box.down == PreopDown("HFS", 26.0, True)
        other.shutdown()
    assert main(["session", "info", str(tmp_path / "case.h5")]) == 0
    assert ("preop down: DICOM HFS (supine, head first), table tilt 26 deg head down (entered)"
            in capsys.readouterr().out.splitlines())


def test_a_session_with_no_node_stored_yet_already_starts_from_gravity(qtbot, panel, pelvic_nodes, tmp_path):
    """Before the first store the session's chain gives the down: the line above Run says gravity, not "a node file"
    (what it said while the session held no node)."""
    xyz, labels = pelvic_nodes
    session = Session.create(tmp_path / "empty.h5", case_id="gui-start-02")
    session.set_calibration(chain=ChainCalibration.manual().with_reference(IMU_AT_REFERENCE))
    try:
        panel.set_session(session)
        load_preop_csv(qtbot, panel, tmp_path / "p.csv", xyz, labels)
        assert panel.start_box.status.text() == f"Next run's {GRAVITY_DEFAULT}."
        session.add_intraop_node("SN1", "", xyz[0])
        panel.refresh_intraop()
        assert panel.start_box.status.text() == f"Next run's {GRAVITY_DEFAULT}."
    finally:
        session.close()
