"""A calibration change with stored nodes (snreg.workflow.chain_change): said plainly, re-expressed exactly on request,
the old values kept on record, mixed calibrations named."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.camera import StereoCalibration, thesis_calibration
from snreg.chain import ChainCalibration, camera_to_trocar, trocar_from_camera
from snreg.nodes import NodeSet
from snreg.session import IntraopNode, Session, calibration_version
from snreg.session.schema import stereo_to_dict
from snreg.workflow.chain_change import calibration_change, mixed_calibration_note, reexpress, retriangulate
from snreg.workflow.registration_run import RunRequest, run_registration

SEED = 1212
CAMERA_COV = np.diag([1.0, 2.0, 25.0])        # mm^2, camera frame: a stereo fix, long along the depth


def _versions(stereo, chain):
    return calibration_version(stereo_to_dict(stereo)), calibration_version(chain.to_dict())


def _store_nodes(session, stereo, chain, rng, n=4):
    """Nodes as Acquisition.store keeps them: camera tip, orientation, trocar tip through ``chain``, versions, and a
    covariance made in the camera frame (long along z) turned into the trocar frame."""
    stereo_version, chain_version = _versions(stereo, chain)
    for k in range(n):
        camera = rng.uniform([-30, -20, 70], [30, 20, 130])
        earth_from_imu = Rotation.from_euler("ZYX", rng.uniform(-15, 15, 3), degrees=True).as_matrix()
        turn = trocar_from_camera(chain, earth_from_imu)[:3, :3]
        session.add_intraop_node(f"SN{k + 1}", "", camera_to_trocar(chain, earth_from_imu, camera), xyz_camera=camera,
                                 earth_from_imu=earth_from_imu, stereo_version=stereo_version,
                                 chain_version=chain_version, cov_trocar_mm2=turn @ CAMERA_COV @ turn.T)


def _pivoted_chain():
    """A chain as the trocar wizard might return: other distances, a tilted mount, a reference pose."""
    tilt = Rotation.from_euler("ZYX", [3.0, -4.0, 2.0], degrees=True).as_matrix()
    manual = ChainCalibration.manual(imu_trocar_mm=430.0, trocar_camera_mm=171.5)
    chain = ChainCalibration(manual.imu_from_camera @ np.block([[tilt, np.zeros((3, 1))], [np.zeros((1, 3)), 1]]),
                             manual.imu_trocar_mm)
    return chain.with_reference(Rotation.from_euler("ZYX", [20.0, 5.0, 0.0], degrees=True).as_matrix())


def test_a_chain_change_is_said_and_reexpresses_the_nodes_exactly(tmp_path):
    rng = np.random.default_rng(SEED)
    stereo, old, new = thesis_calibration(), ChainCalibration.manual(), _pivoted_chain()
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="chain-1") as session:
        session.set_calibration(stereo=stereo, chain=old)
        _store_nodes(session, stereo, old, rng)
        assert calibration_change(session, stereo, old) is None
        before = {node.id: node for node in session.intraop_records()}
        change = calibration_change(session, stereo, new)
        assert change.chain_changed and not change.stereo_changed and not change.stuck
        assert change.message.startswith("The trocar calibration (chain) changed. SN1, SN2, SN3 and SN4 were stored")
        assert "Re-express SN1, SN2, SN3 and SN4 under the new calibration?" in change.question
        moved = reexpress(session, stereo, new)
        assert [node.id for node in moved] == ["SN1", "SN2", "SN3", "SN4"]
        assert calibration_change(session, stereo, new) is None
    with Session.open(path) as session:
        for node in session.intraop_records():
            old_node = before[node.id]
            expected = camera_to_trocar(new, old_node.earth_from_imu, old_node.xyz_camera)
            np.testing.assert_allclose(node.xyz_trocar, expected, atol=1e-9)
            np.testing.assert_allclose(node.xyz_camera, old_node.xyz_camera)
            assert node.measured_under == _versions(stereo, new)
            turn = trocar_from_camera(new, old_node.earth_from_imu)[:3, :3]     # the covariance turned with the node
            np.testing.assert_allclose(node.cov_trocar_mm2, turn @ CAMERA_COV @ turn.T, atol=1e-9)
        [event] = session.events("nodes_reexpressed")
        kept = {change["id"]: change["old"] for change in event["nodes"]}
        for node_id, old_node in before.items():        # the positions as first stored stay on record
            np.testing.assert_allclose(kept[node_id]["xyz_trocar"], old_node.xyz_trocar)
            np.testing.assert_allclose(kept[node_id]["cov_trocar_mm2"], old_node.cov_trocar_mm2)
            assert kept[node_id]["chain_version"] == old_node.chain_version


def test_a_stereo_change_retriangulates_from_the_pixels_the_old_calibration_saw():
    old = thesis_calibration().scaled(0.5)
    new = StereoCalibration.from_pair(old.image_size, old.K1, old.D1, old.K2, old.D2, old.R,
                                      np.asarray(old.T) * 1.05)
    point = np.array([12.0, -7.0, 95.0])
    np.testing.assert_allclose(retriangulate(point, old, old), point, atol=1e-6)
    moved = retriangulate(point, old, new)
    assert 1.0 < np.linalg.norm(moved - point) < 10.0
    # the new calibration projects the re-triangulated tip where the old one saw the original
    for eye, (K, R, T) in enumerate(((old.K1, np.eye(3), np.zeros(3)), (old.K2, old.R, np.ravel(old.T)))):
        seen = K @ (R @ point + T)
        K_new, T_new = (new.K1, np.zeros(3)) if eye == 0 else (new.K2, np.ravel(new.T))
        again = K_new @ ((np.eye(3) if eye == 0 else new.R) @ moved + T_new)
        np.testing.assert_allclose(again[:2] / again[2], seen[:2] / seen[2], atol=1e-6)


def test_nodes_without_orientation_or_of_an_unknown_stereo_calibration_are_named_not_moved(tmp_path):
    stereo, chain = thesis_calibration(), ChainCalibration.manual()
    other = StereoCalibration.from_pair(stereo.image_size, stereo.K1, stereo.D1, stereo.K2, stereo.D2, stereo.R,
                                        np.asarray(stereo.T) * 1.1)
    with Session.create(tmp_path / "s.h5", case_id="chain-2") as session:
        session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0], xyz_camera=[1.0, 2.0, 90.0])    # as format 1 kept it
        session.add_intraop_node("SN2", "", [1.0, 2.0, 3.0], xyz_camera=[1.0, 2.0, 90.0], earth_from_imu=np.eye(3),
                                 stereo_version=_versions(other, chain)[0], chain_version=_versions(other, chain)[1])
        change = calibration_change(session, stereo, chain)             # 'other' is not the calibration replaced
        assert change.movable == [] and [n.id for n in change.stuck] == ["SN1", "SN2"]
        assert "SN1 and SN2 cannot be re-expressed" in change.message and change.question == ""
        assert reexpress(session, stereo, chain) == []
        assert session.events("nodes_reexpressed") == []
        change = calibration_change(session, stereo, chain, previous_stereo=other)   # it is: SN2 can move
        assert [n.id for n in change.movable] == ["SN2"] and change.stereo_changed
        [moved] = reexpress(session, stereo, chain, previous_stereo=other)
        np.testing.assert_allclose(moved.xyz_camera, retriangulate([1.0, 2.0, 90.0], other, stereo))


def test_a_registration_over_two_calibrations_is_named():
    def node(node_id, chain_version):
        return IntraopNode(node_id, "", 0, np.zeros(3), np.zeros(3), 0.0, 0, 0.0, stereo_version="5e5e5e5e",
                           chain_version=chain_version)

    same = [node("SN1", "c0c0c0c0"), node("SN2", "c0c0c0c0")]
    assert mixed_calibration_note(same) == ""
    note = mixed_calibration_note(same + [node("SN3", "0badc0de")])
    assert note == ("These nodes were mapped with 2 different calibrations (SN1 and SN2 under stereo 5e5e5e5e, chain "
                    "c0c0c0c0; SN3 under stereo 5e5e5e5e, chain 0badc0de): a registration mixes two frames; re-express "
                    "the older nodes (Acquisition) or undo them first.")


def test_a_registration_run_on_mixed_nodes_says_so_first(tmp_path):
    rng = np.random.default_rng(SEED)
    stereo = thesis_calibration()
    with Session.create(tmp_path / "s.h5", case_id="chain-3") as session:
        _store_nodes(session, stereo, ChainCalibration.manual(), rng, n=3)
        camera = np.array([5.0, 5.0, 100.0])
        session.add_intraop_node("SN4", "", camera_to_trocar(_pivoted_chain(), np.eye(3), camera), xyz_camera=camera,
                                 earth_from_imu=np.eye(3), stereo_version=_versions(stereo, _pivoted_chain())[0],
                                 chain_version=_versions(stereo, _pivoted_chain())[1])
        intraop = session.intraop_nodes()
        preop = NodeSet(["P1", "P2", "P3", "P4"], [""] * 4, intraop.xyz + 1.0, frame="LPS")
        record = run_registration(RunRequest(preop, intraop, "icp", False, np.eye(4), 60.0, 60.0, session=session))
    assert record.note.startswith("These nodes were mapped with 2 different calibrations (SN1, SN2 and SN3 under ")
    assert record.note.endswith("Stored in the session as registration 0.")


def test_a_new_trocar_calibration_keeps_each_tracked_nodes_slide_since_the_start(tmp_path):
    """A node stored at a tracked insertion d under a chain starting at s is mapped again at s' + (d - s) under a
    chain starting at s'; a node stored untracked at the new chain's own distance (issue 27)."""
    rng = np.random.default_rng(SEED)
    stereo, old, new = thesis_calibration(), ChainCalibration.manual(), _pivoted_chain()      # starts 158 and 171.5
    stereo_version, chain_version = _versions(stereo, old)
    cameras = rng.uniform([-30, -20, 70], [30, 20, 130], (2, 3))
    turned = Rotation.from_euler("ZYX", [8.0, -6.0, 3.0], degrees=True).as_matrix()
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="chain-4") as session:
        session.set_calibration(stereo=stereo, chain=old)
        session.add_intraop_node("SN1", "", camera_to_trocar(old.with_insertion(170.0), turned, cameras[0]),
                                 xyz_camera=cameras[0], earth_from_imu=turned, stereo_version=stereo_version,
                                 chain_version=chain_version, trocar_camera_mm=170.0)    # slid 12 mm in, tracked
        session.add_intraop_node("SN2", "", camera_to_trocar(old, turned, cameras[1]), xyz_camera=cameras[1],
                                 earth_from_imu=turned, stereo_version=stereo_version, chain_version=chain_version)
        session.set_calibration(chain=new)               # as the trocar wizard does before the offer
        unknown = calibration_change(session, stereo, new)
        assert [n.id for n in unknown.stuck] == ["SN1"] and [n.id for n in unknown.movable] == ["SN2"]
        change = calibration_change(session, stereo, new, previous_chain=old)
        assert not change.stuck and change.starts == {"SN1": pytest.approx(old.trocar_camera_mm)}
        assert ("SN1 was stored with the camera's insertion tracked: the slide tracked since the start is kept and "
                "added to the new trocar-camera distance.") in change.question
        reexpress(session, stereo, new, previous_chain=old)
        assert calibration_change(session, stereo, new) is None
    with Session.open(path) as session:
        first, second = session.intraop_records()
        [event] = session.events("nodes_reexpressed")
    assert first.trocar_camera_mm == pytest.approx(171.5 + 12.0)
    np.testing.assert_allclose(first.xyz_trocar, camera_to_trocar(new.with_insertion(183.5), turned, cameras[0]),
                               atol=1e-9)
    assert np.isnan(second.trocar_camera_mm)
    np.testing.assert_allclose(second.xyz_trocar, camera_to_trocar(new, turned, cameras[1]), atol=1e-9)
    old_values = {change["id"]: change["old"] for change in event["nodes"]}
    assert old_values["SN1"]["trocar_camera_mm"] == 170.0 and np.isnan(old_values["SN2"]["trocar_camera_mm"])


def test_a_stereo_change_leaves_a_tracked_insertion_as_it_was(tmp_path):
    stereo, chain = thesis_calibration(), ChainCalibration.manual()
    longer = StereoCalibration.from_pair(stereo.image_size, stereo.K1, stereo.D1, stereo.K2, stereo.D2, stereo.R,
                                         np.asarray(stereo.T) * 1.05)
    camera = np.array([4.0, -3.0, 95.0])
    with Session.create(tmp_path / "s.h5", case_id="chain-5") as session:
        session.set_calibration(stereo=stereo, chain=chain)
        session.add_intraop_node("SN1", "", camera_to_trocar(chain.with_insertion(150.0), np.eye(3), camera),
                                 xyz_camera=camera, earth_from_imu=np.eye(3), stereo_version=_versions(stereo, chain)[0],
                                 chain_version=_versions(stereo, chain)[1], trocar_camera_mm=150.0)
        [moved] = reexpress(session, longer, chain, previous_stereo=stereo)
    assert moved.trocar_camera_mm == 150.0
    np.testing.assert_allclose(moved.xyz_trocar, camera_to_trocar(chain.with_insertion(150.0), np.eye(3),
                                                                  retriangulate(camera, stereo, longer)), atol=1e-9)
