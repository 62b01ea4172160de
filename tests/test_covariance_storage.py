"""Each node's covariance kept and used (issue 28): computed by the acquisition at each store, in the session file, the
journal, ``session info`` and the node CSV (NaN in files written before it was stored), re-expressed with the node;
each hot spot's from a synthetic SPECT, stored with the preop nodes; ``snreg register`` weighing both sides by them
unless told not to, and saying so."""

import json

import h5py
import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration, trocar_from_camera
from snreg.cli import main
from snreg.demo.scene import PhantomScene, Schedule
from snreg.demo.spect import THESIS_VOXEL_MM, spect_of_nodes, write_nm
from snreg.errors import NodeFileError
from snreg.nodes import NodeSet, read_nodes
from snreg.preop import load_volume, segment_nodes
from snreg.preop.segment import hot_spot_covariance
from snreg.probe import default_probe_model
from snreg.session import Session
from snreg.session.export import session_info
from snreg.session.journal import _line, journal_path, read_journal
from snreg.sources import StereoFrame
from snreg.tracking.uncertainty import NodeUncertainty
from snreg.workflow.acquisition import Acquisition, ImuReading
from snreg.workflow.chain_change import reexpress

COV = np.array([[4.0, 1.0, 0.0], [1.0, 9.0, 2.0], [0.0, 2.0, 16.0]])


def test_a_nodes_covariance_is_in_the_file_the_journal_session_info_and_the_node_set(tmp_path, capsys):
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="cov-1") as session:
        session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0], cov_trocar_mm2=COV)
        session.add_intraop_node("SN2", "INT L", [4.0, 5.0, 6.0])                 # stored without one
    with Session.open(path) as session:
        first, second = session.intraop_records()
        nodes = session.intraop_nodes()
    np.testing.assert_array_equal(first.cov_trocar_mm2, COV)
    assert np.isnan(second.cov_trocar_mm2).all()
    np.testing.assert_array_equal(nodes.cov[0], COV)
    assert np.isnan(nodes.cov[1]).all() and nodes.known_cov is None
    with h5py.File(path) as h5:
        assert h5["nodes/intraop/cov_trocar_mm2"].fletcher32
    info = session_info(path)
    assert [node["cov_trocar_mm2"] for node in info["nodes"]] == [COV.tolist(), None]
    assert main(["session", "info", str(path)]) == 0
    radius = np.sqrt(6.2514 * np.linalg.eigvalsh(COV)[-1])          # chi-square 90 % with 3 dof
    assert f"node errors, 90 % ellipsoid's longest semi-axis: SN1 {radius:.1f} mm, SN2 unknown" in \
        capsys.readouterr().out
    assert main(["session", "export", str(path), "--format", "csv", "-o", str(tmp_path / "n.csv")]) == 0
    exported = read_nodes(tmp_path / "n.csv")
    np.testing.assert_array_equal(exported.cov[0], COV)
    assert np.isnan(exported.cov[1]).all()
    path.unlink()                                               # the journal alone holds it too
    with Session.open(path) as session:
        first, second = session.intraop_records()
    np.testing.assert_array_equal(first.cov_trocar_mm2, COV)
    assert np.isnan(second.cov_trocar_mm2).all()


def test_files_written_before_the_covariance_read_nan_and_take_it_when_continued(tmp_path):
    path = tmp_path / "old.h5"
    with Session.create(path, case_id="cov-2") as session:
        session.add_intraop_node("SN1", "OBT R", [1.0, 2.0, 3.0], cov_trocar_mm2=COV)
    with h5py.File(path, "r+") as h5:                           # as snreg wrote format 4 before the covariance
        del h5["nodes/intraop/cov_trocar_mm2"]
    journal = journal_path(path)
    old = [(kind, {k: v for k, v in data.items() if k != "cov_trocar_mm2"}) for kind, data in
           read_journal(journal).entries]
    journal.write_bytes(b"".join(_line(kind, data) for kind, data in old))
    with Session.open(path) as session:
        [node] = session.intraop_records()
        assert not session.damaged and session.problems == [] and np.isnan(node.cov_trocar_mm2).all()
        assert session.intraop_nodes().cov is None
    with Session.resume(path) as session:
        session.add_intraop_node("SN2", "", [4.0, 5.0, 6.0], cov_trocar_mm2=2 * COV)
    with Session.open(path) as session:
        first, second = session.intraop_records()
        assert not session.damaged and np.isnan(first.cov_trocar_mm2).all()
        np.testing.assert_array_equal(second.cov_trocar_mm2, 2 * COV)


def test_a_reexpression_states_the_new_covariance_and_keeps_the_old_on_record(tmp_path):
    import dataclasses
    path = tmp_path / "s.h5"
    with Session.create(path, case_id="cov-3") as session:
        node = session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0], cov_trocar_mm2=COV)
        session.reexpress_nodes([dataclasses.replace(node, xyz_trocar=np.array([1.0, 2.0, 5.0]),
                                                     cov_trocar_mm2=3 * COV)], "test")
    for reopen in (False, True):
        if reopen:
            path.unlink()                                       # replayed from the journal
        with Session.open(path) as session:
            [node] = session.intraop_records()
            [event] = session.events("nodes_reexpressed")
        np.testing.assert_array_equal(node.cov_trocar_mm2, 3 * COV)
        assert event["nodes"][0]["old"]["cov_trocar_mm2"] == COV.tolist()


def test_a_node_measured_under_a_chain_no_longer_known_loses_its_covariance_when_reexpressed(tmp_path):
    stereo, unknown, new = thesis_calibration(), ChainCalibration.manual(trocar_camera_mm=150.0), ChainCalibration.manual()
    from snreg.session import calibration_version
    from snreg.session.schema import stereo_to_dict
    with Session.create(tmp_path / "s.h5", case_id="cov-4") as session:
        session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0], xyz_camera=[1.0, 2.0, 90.0], earth_from_imu=np.eye(3),
                                 stereo_version=calibration_version(stereo_to_dict(stereo)),
                                 chain_version=calibration_version(unknown.to_dict()), cov_trocar_mm2=COV)
        [moved] = reexpress(session, stereo, new)
    assert np.isnan(moved.cov_trocar_mm2).all()


@pytest.fixture(scope="module")
def scene():
    return PhantomScene(thesis_calibration().scaled(0.5), default_probe_model(), Schedule(rest_frames=10, move_frames=1,
                                                                                        noise_variants=2))


def test_the_acquisition_stores_each_nodes_covariance_from_its_geometry(tmp_path, scene):
    chain = ChainCalibration.manual().with_reference(np.eye(3))
    with Session.create(tmp_path / "s.h5", case_id="cov-5", stream_flush_s=0) as session:
        acquisition = Acquisition(scene.renderer.calibration, default_probe_model(), chain, session, fixes_per_node=4)
        quiet = Acquisition(scene.renderer.calibration, default_probe_model(), chain, session, fixes_per_node=4,
                            uncertainty=NodeUncertainty(residual_mm=0.0, pointing_lateral_mm=0.0,
                                                        pointing_axial_mm=0.0))
        for node, who in ((0, acquisition), (2, quiet)):
            for index in range(4):
                left, right = scene.render(node * (scene.schedule.rest_frames + scene.schedule.move_frames) + index % 2)
                who.process(StereoFrame(left, right, 10**6 * (10 * node + index), 10**6 * (10 * node + index), index),
                            ImuReading(np.eye(3)))
            who.store(session.next_node_id(), "")
    with Session.open(tmp_path / "s.h5") as session:
        full, stereo_only = session.intraop_records()
    for node in (full, stereo_only):
        assert np.allclose(node.cov_trocar_mm2, node.cov_trocar_mm2.T) and np.linalg.eigvalsh(node.cov_trocar_mm2)[0] > 0
    # the thesis' residual (2.8 mm per axis) and pointing (5 mm radius, 5 mm ahead) make up most of a node's error
    assert 20.0 < np.trace(full.cov_trocar_mm2) < 60.0
    # without them: the stereo ray (camera z at the reference pose, trocar z) and the unseen insertion along the shaft
    sd, axes = np.linalg.eigh(stereo_only.cov_trocar_mm2)
    ray = trocar_from_camera(chain, np.eye(3))[:3, :3] @ (stereo_only.xyz_camera / np.linalg.norm(stereo_only.xyz_camera))
    assert abs(axes[:, 2] @ ray) > 0.95 and sd[2] > 4 * sd[1]


def test_a_hot_spots_covariance_is_small_for_a_lone_node_and_long_along_merged_ones(tmp_path):
    lone = np.array([[-40.0, 30.0, 50.0], [45.0, 40.0, 60.0]])
    counts, origin = spect_of_nodes(lone, seed=2, peak_counts=2000.0)
    result = segment_nodes(load_volume(write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "lone.dcm")[0]), n_nodes=2)
    assert result.nodes.cov.shape == (2, 3, 3)
    assert np.sqrt(np.linalg.eigvalsh(result.nodes.cov).max()) < 0.3                # the counts' noise alone
    merged = np.array([[-5.0, 40.0, 50.0], [5.0, 40.0, 50.0]])                          # 10 mm apart: one hot spot
    counts, origin = spect_of_nodes(merged, seed=2, peak_counts=2000.0)
    [cov] = segment_nodes(load_volume(write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "two.dcm")[0]),
                          n_nodes=1).nodes.cov
    variance, axes = np.linalg.eigh(cov)
    assert abs(axes[0, 2]) > 0.99 and 15.0 < variance[2] < 35.0     # along x, about (10 / 2)^2: where a node may lie
    assert variance[1] < 1.0


def test_snreg_preop_writes_each_centres_covariance(tmp_path, capsys):
    from snreg.cli import preop as cli_preop
    from snreg.preop.segment import RESOLUTION_MM

    assert cli_preop.RESOLUTION_MM == RESOLUTION_MM               # stated in the parser, which imports no numpy
    counts, origin = spect_of_nodes(np.array([[-40.0, 30.0, 50.0], [45.0, 40.0, 60.0]]), seed=2)
    spect = write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "s.dcm")[0]
    assert main(["preop", str(spect), "-o", str(tmp_path / "p.csv"), "--resolution", "10"]) == 0
    assert "sd mm" in capsys.readouterr().out
    nodes = read_nodes(tmp_path / "p.csv")
    assert nodes.known_cov is not None and nodes.frame == "LPS"
    assert main(["preop", str(spect), "-o", str(tmp_path / "q.csv"), "--resolution", "0"]) == 2
    assert "resolution" in capsys.readouterr().err


def test_the_counts_noise_part_is_the_weighted_centroids_own_variance():
    rng = np.random.default_rng(5)
    positions = rng.uniform(-10, 10, (50, 3))
    mean = 50.0 * np.exp(-np.sum(positions**2, axis=1) / 50.0) + 20.0
    # far above the level, a hot spot as wide as a point's image: only the counts' noise is left
    cov = hot_spot_covariance(positions, mean, 10.0, resolution_mm=60.0)
    centres = []
    for _ in range(4000):
        values = rng.poisson(mean).astype(float)
        weight = values - 10.0
        centres.append(weight @ positions / weight.sum())
    np.testing.assert_allclose(np.cov(np.array(centres), rowvar=False), cov, rtol=0.15, atol=0.002)


def test_node_files_carry_the_covariance_in_six_columns():
    nodes = NodeSet(["P1", "P2"], ["", ""], np.zeros((2, 3)), cov=np.array([COV, np.full((3, 3), np.nan)]))
    text = nodes.to_csv()
    assert text.splitlines()[0] == "id,label,x,y,z,cov_xx,cov_xy,cov_xz,cov_yy,cov_yz,cov_zz"
    back = NodeSet.from_csv(text)
    np.testing.assert_array_equal(back.cov[0], COV)
    assert np.isnan(back.cov[1]).all()
    with pytest.raises(NodeFileError, match="all six columns"):
        NodeSet.from_csv("id,label,x,y,z,cov_xx\nP1,,0,0,0,1\n")
    with pytest.raises(NodeFileError, match="not a number"):
        NodeSet.from_csv("id,label,x,y,z,cov_xx,cov_xy,cov_xz,cov_yy,cov_yz,cov_zz\nP1,,0,0,0,1,0,0,1,,1\n")


def _session_with_both_sides(path, rng):
    """A session whose intraop nodes (trocar frame) are its preop nodes moved, each side with its covariances."""
    preop = NodeSet.from_xyz(rng.uniform(-60, 60, (6, 3)), prefix="P", frame="LPS",
                             cov=np.repeat(0.5 * np.eye(3)[None], 6, axis=0))
    rays = rng.normal(size=(6, 3))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    intraop_cov = 2.0 * np.eye(3) + 30.0 * rays[:, :, None] * rays[:, None, :]
    intraop = preop.xyz + [5.0, -3.0, 2.0] + np.einsum("nij,nj->ni", np.linalg.cholesky(intraop_cov),
                                                        rng.normal(size=(6, 3)))
    with Session.create(path, case_id="cov-6") as session:
        session.set_preop_nodes(preop)
        for k in range(6):
            session.add_intraop_node(f"SN{k + 1}", "", intraop[k], cov_trocar_mm2=intraop_cov[k])
    return preop


def test_preop_covariances_are_stored_with_the_preop_nodes(tmp_path, rng):
    path = tmp_path / "s.h5"
    preop = _session_with_both_sides(path, rng)
    for reopen in (False, True):
        if reopen:
            path.unlink()
        with Session.open(path) as session:
            np.testing.assert_array_equal(session.preop_nodes().cov, preop.cov)


def test_register_weighs_both_sides_by_their_covariances_and_says_so(tmp_path, rng, capsys):
    path = tmp_path / "s.h5"
    _session_with_both_sides(path, rng)
    assert main(["register", str(path), "--json"]) == 0
    used = json.loads(capsys.readouterr().out)
    assert used["covariances"] == {"intraop": True, "preop": True}
    assert main(["register", str(path), "--json", "--no-covariances"]) == 0
    without = json.loads(capsys.readouterr().out)
    assert without["covariances"] == {"intraop": False, "preop": False}
    assert [n["preop_id"] for n in used["nodes"]] == [f"P{k + 1}" for k in range(6)]
    assert used["rms_mm"] != without["rms_mm"]                    # the weighted fit is another fit
    assert main(["register", str(path)]) == 0
    assert "used: each stored node's and each hot spot's own error (covariance)" in capsys.readouterr().out
    assert main(["register", str(path), "--no-covariances"]) == 0
    assert "the nodes' own errors (covariances: --no-covariances)" in capsys.readouterr().out.split("not used:")[1]
    with Session.open(path) as session:
        session.preop_nodes().to_csv()
        (tmp_path / "p.csv").write_text(NodeSet(session.preop_nodes().ids, session.preop_nodes().labels,
                                                session.preop_nodes().xyz).to_csv())
    assert main(["register", str(tmp_path / "p.csv"), str(path)]) == 0
    out = capsys.readouterr().out
    assert "used: each stored node's own error (covariance)" in out
    assert "the hot spots' covariances (the preop nodes have none)" in out.split("not used:")[1]
