"""Offline review data (snreg.session.timeline): a session read back as plot-ready arrays, against its ground truth."""

import shutil
from dataclasses import dataclass, replace

import h5py
import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.imu_motion import MotionProfile, rotate, still
from snreg.demo.imu_simulator import ImuSimulator
from snreg.nodes import NodeSet
from snreg.registration import register
from snreg.session import Session, SessionError
from snreg.session.journal import Journal, journal_path, read_journal
from snreg.session.schema import FORMAT_VERSION
from snreg.session.timeline import (GAP_PERIODS, ImuSeries, clock_figures, frame_series, fuse_imu, fuse_imu_blocks,
                                    gap_after, imu_gap_after, load_review, with_gaps)

T0_NS = 5_000_000_000_000          # host clock at the first IMU sample
YAW_TURN_DEG = 10.0
DURATION_S = 7.0                   # still 3 s (the filter's start-up and bias estimate), turn 2 s, still 2 s
PREOP = np.array([[0.0, 0.0, 0.0], [40.0, 5.0, 0.0], [5.0, 50.0, 10.0], [30.0, 40.0, 35.0]])
PREOP_IDS = ["P1", "P2", "P3", "P4"]
STEREO_RMS_PX = 0.42
CAMERA_LAG_S = 0.003               # probe and frame rows start this long after the first IMU sample
FRAME_RATE_HZ = 30
LOST_FRAMES = range(120, 135)      # 4.0 s to 4.5 s at 30 Hz: one gap


@dataclass
class Recorded:
    """Ground truth of a session written by :func:`record_session`."""

    node_ids: list
    node_times_s: list
    snapshot_shapes: list          # (left (H, W, 3), right (H, W, 3)) per node
    rms_mm: float
    frame_times_s: np.ndarray


def _host_ns(t_s):
    return T0_NS + np.round(np.asarray(t_s) * 1e9).astype(np.int64)


def _frame_times(n):
    k = np.arange(n)
    return k[~np.isin(k, LOST_FRAMES)] / FRAME_RATE_HZ


def _snapshot(height, width, bgr):
    return np.broadcast_to(np.array(bgr, np.uint8), (height, width, 3)).copy()


def record_session(path) -> Recorded:
    """A 7 s session: a 10 deg yaw turn on a simulated IMU whose clock wraps, 30 Hz probe and frames with one gap,
    three nodes with snapshots of known sizes (left pure red, right pure blue), calibration and a registration."""
    profile = MotionProfile([still(3.0), rotate((0.0, 0.0, 1.0), YAW_TURN_DEG, 5.0), still(2.0)])
    n_imu = int(DURATION_S * 208)
    imu = ImuSimulator(profile, seed=7, n_samples=n_imu, start_us=(1 << 32) - 2_000_000).readings(n_imu)
    t_probe = np.arange(int(DURATION_S * FRAME_RATE_HZ)) / FRAME_RATE_HZ
    frames = _frame_times(int(DURATION_S * FRAME_RATE_HZ))
    tip = np.column_stack([t_probe, 2 * t_probe, 100 + t_probe])
    node_times = [1.5, 4.2, 6.5]
    shapes = [((48, 64, 3), (40, 56, 3)), ((30, 40, 3), (30, 40, 3)), ((24, 32, 3), (26, 36, 3))]
    xyz = PREOP[:3] + [1.0, -0.5, 0.8] + np.diag([0.6, -0.8, 0.5])
    with Session.create(path, case_id="review-01", stream_flush_s=0) as s:
        s.set_calibration(stereo=replace(thesis_calibration(), rms_reprojection_px=STEREO_RMS_PX),
                          chain=ChainCalibration.manual())
        s.set_preop_nodes(NodeSet(PREOP_IDS, [""] * 4, PREOP, frame="LPS"))
        s.append_imu(_host_ns(imu.t_s), imu.t_device_us * 1000, imu.accel_g, imu.gyro_dps)
        host = _host_ns(t_probe + CAMERA_LAG_S)
        s.append_probe(host, host, tip, tip + [0.0, 0.0, 30.0], np.tile([0.0, 0.0, 1.0], (len(host), 1)),
                       np.full(len(host), 0.9))
        frame_host = _host_ns(frames + CAMERA_LAG_S)
        s.append_frames(frame_host, frame_host, np.arange(len(frames)))
        for k, (t, (left, right)) in enumerate(zip(node_times, shapes)):
            s.add_intraop_node(f"SN{k + 1}", "OBT R", xyz[k], xyz_camera=xyz[k] + 100, spread_mm=0.5, n_frames=60,
                               counts=50.0 * k, time_ns=_host_ns(t), left_jpeg=_snapshot(*left[:2], (0, 0, 255)),
                               right_jpeg=_snapshot(*right[:2], (255, 0, 0)))
        result = register(PREOP, xyz, method="global", seed=0)
        s.add_registration(result, PREOP_IDS, [f"SN{k + 1}" for k in range(3)])
    return Recorded(["SN1", "SN2", "SN3"], node_times, shapes, float(result.rms_mm), frames + CAMERA_LAG_S)


def damaged_copy(path, folder):
    """A copy of the session at ``path`` whose HDF5 file is truncated, its journal intact."""
    copy = folder / "damaged.h5"
    copy.write_bytes(path.read_bytes()[:2000])
    shutil.copyfile(journal_path(path), journal_path(copy))
    return copy


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("review") / "s.h5"
    return path, record_session(path)


def test_load_review_copies_header_nodes_and_snapshots(recorded):
    path, truth = recorded
    review = load_review(path)
    assert (review.case_id, review.format_version, review.damaged) == ("review-01", FORMAT_VERSION, False)
    assert review.created_utc.endswith("+00:00") and review.snreg_version
    assert review.stereo_rms_px == pytest.approx(STEREO_RMS_PX)
    assert (review.imu_trocar_mm, review.trocar_camera_mm) == pytest.approx((460.0, 158.0))
    assert review.t0_ns == T0_NS
    assert [n.id for n in review.nodes] == truth.node_ids
    np.testing.assert_allclose([n.t_s for n in review.nodes], truth.node_times_s, atol=1e-9)
    for node, (left, right) in zip(review.nodes, truth.snapshot_shapes):
        assert node.left_rgb.shape == left and node.right_rgb.shape == right
        np.testing.assert_allclose(node.left_rgb.reshape(-1, 3).mean(0), [255, 0, 0], atol=3)    # stored red (BGR)
        np.testing.assert_allclose(node.right_rgb.reshape(-1, 3).mean(0), [0, 0, 255], atol=3)
    np.testing.assert_allclose(review.nodes[1].xyz_camera - review.nodes[1].xyz_trocar, 100.0)
    with h5py.File(path, "r+"):            # nothing of ours holds the file any more
        pass


def test_streams_share_the_time_axis(recorded):
    path, truth = recorded
    review = load_review(path)
    np.testing.assert_allclose(review.imu.t_s[[0, -1]], [0.0, (len(review.imu.t_s) - 1) / 208], atol=1e-9)
    np.testing.assert_allclose(review.probe.t_s[:2], [CAMERA_LAG_S, CAMERA_LAG_S + 1 / 30], atol=1e-9)
    np.testing.assert_allclose(review.probe.tip_mm[:, 1], 2 * (review.probe.t_s - CAMERA_LAG_S), atol=1e-4)
    np.testing.assert_allclose(review.probe.quality, 0.9, atol=1e-6)
    np.testing.assert_allclose(review.frames.t_s, truth.frame_times_s, atol=1e-9)


def test_frame_rate_and_gaps():
    frames = frame_series(_frame_times(10 * FRAME_RATE_HZ))
    assert frames.median_rate_hz == pytest.approx(FRAME_RATE_HZ)
    first, after = LOST_FRAMES[0] - 1, LOST_FRAMES[-1] + 1
    np.testing.assert_allclose(frames.gaps_s, [[first / FRAME_RATE_HZ, (after - first) / FRAME_RATE_HZ]])
    times = _frame_times(10 * FRAME_RATE_HZ)
    jittered = frame_series(times + 0.01 * (np.arange(len(times)) % 2))
    assert len(jittered.gaps_s) == 1                     # late frames are not gaps; GAP_PERIODS periods are
    assert frame_series(np.arange(10) * (GAP_PERIODS + 0.5)).gaps_s.shape == (0, 2)
    assert len(frames.rate_edges_s) == len(frames.rate_hz) + 1
    whole = frames.rate_edges_s[:-1] != 4.0
    np.testing.assert_array_equal(frames.rate_hz[whole], FRAME_RATE_HZ)
    assert frames.rate_hz[~whole] == [FRAME_RATE_HZ / 2]                # half of second 4 was lost


def test_recording_gaps_break_a_curve_instead_of_bridging_it():
    t = np.concatenate([np.arange(10) / 30, 95.0 + np.arange(10) / 30])      # paused 95 s for a calibration
    after = gap_after(t)
    assert list(after) == [9] and list(gap_after(t, period_s=100.0)) == []
    t_drawn, values = with_gaps(t, np.column_stack([t, 2 * t]), after)
    assert len(t_drawn) == 21 and np.isnan(t_drawn[10]) and np.isnan(values[10]).all()
    np.testing.assert_array_equal(values[11:, 1], 2 * t[10:])
    assert len(gap_after(np.arange(10) * 0.01 * (1 + 0.1 * (np.arange(10) % 2)))) == 0    # jitter is not a gap


def test_imu_gaps_are_judged_on_the_boards_clock_not_the_bursts_the_host_stamps_them_in():
    device_us = (1 << 32) - 100_000 + np.arange(600) * 4808            # 208 Hz on the board's clock, which wraps
    device_us[300:] += 1_000_000                                        # the board paused 1 s after sample 299
    device_us[450:] -= device_us[450] - 1000                            # and restarted (its clock back to 0) at 450
    device_us %= 1 << 32
    host_s = np.repeat(np.arange(120) * 0.024, 5)                       # the reader gets them 5 at a time
    imu = ImuSeries(host_s, device_us, np.zeros((600, 3)), np.zeros((600, 3)))
    assert np.median(np.diff(host_s)) == 0 and len(gap_after(host_s)) > 100   # the host's median: a gap everywhere
    assert list(imu_gap_after(imu)) == [299, 449]


def test_fused_yaw_follows_the_applied_turn(recorded):
    path, _ = recorded
    review = load_review(path)
    euler = fuse_imu(review.imu)
    assert euler.shape == (len(review.imu.t_s), 3)
    assert euler[-1, 0] == pytest.approx(YAW_TURN_DEG, abs=0.5)
    np.testing.assert_allclose(euler[-1, 1:], 0.0, atol=0.3)
    assert abs(euler[review.imu.t_s < 2.9, 0]).max() < 0.3                 # still before the turn


def test_fusion_blocks_continue_one_filter(recorded):
    path, _ = recorded
    review = load_review(path)
    blocks = list(fuse_imu_blocks(review.imu, block=500))
    assert [len(b) for b in blocks] == [500, 500, 456]
    np.testing.assert_array_equal(np.concatenate(blocks), fuse_imu(review.imu))


def test_registration_pairing_table(recorded):
    path, truth = recorded
    (reg,) = load_review(path).registrations
    assert (reg.n, reg.method, reg.n_paired) == (0, "global", 3)
    assert reg.rms_mm == pytest.approx(truth.rms_mm)
    assert reg.intraop_ids == truth.node_ids and reg.preop_ids == PREOP_IDS[:3]
    assert reg.distances_mm.shape == reg.confidence.shape == (3,)


def test_a_damaged_file_is_reviewed_from_its_journal(recorded, tmp_path):
    path, truth = recorded
    review = load_review(damaged_copy(path, tmp_path))
    assert review.damaged and review.case_id == "review-01" and review.stereo_rms_px == pytest.approx(STEREO_RMS_PX)
    assert [n.id for n in review.nodes] == truth.node_ids and len(review.registrations) == 1
    assert len(review.imu.t_s) == len(review.probe.t_s) == len(review.frames.t_s) == 0
    np.testing.assert_allclose([n.t_s for n in review.nodes], np.subtract(truth.node_times_s, truth.node_times_s[0]))
    assert fuse_imu(review.imu).shape == (0, 3)


def test_unreadable_files_give_one_sentence(tmp_path):
    text = tmp_path / "notes.h5"
    text.write_text("not a session\n")
    for path in (text, tmp_path / "missing.h5"):
        with pytest.raises(SessionError, match=str(path.name)) as err:
            load_review(path)
        assert "\n" not in str(err.value)


def test_a_registration_keeps_its_node_names_after_an_undo_and_a_new_preop_set(tmp_path):
    path = tmp_path / "s.h5"
    xyz = PREOP[:3] + [1.0, -0.5, 0.8]
    with Session.create(path, case_id="review-02") as s:
        s.set_preop_nodes(NodeSet(PREOP_IDS, [""] * 4, PREOP, frame="LPS"))
        for k in range(3):
            s.add_intraop_node(f"SN{k + 1}", "", xyz[k])
        s.add_registration(register(PREOP, xyz, method="global"), PREOP_IDS, ["SN1", "SN2", "SN3"])
        s.remove_intraop_node("SN3")                                   # undo
        s.set_preop_nodes(NodeSet(["Q1", "Q2"], ["", ""], PREOP[:2], frame="LPS"))   # re-segmented
    (reg,) = load_review(path).registrations
    assert reg.intraop_ids == ["SN1", "SN2", "SN3"] and reg.preop_ids == ["P1", "P2", "P3"]


def test_a_file_written_before_ids_were_stored_names_rows_from_its_node_lists(recorded, tmp_path):
    path, truth = recorded
    old = tmp_path / "old.h5"
    shutil.copyfile(path, old)
    with h5py.File(old, "r+") as h5:
        for key in ("preop_ids", "intraop_ids", "initial"):
            del h5["registration/0"][key]
    entries = read_journal(journal_path(path)).entries
    journal = Journal(journal_path(old))
    for kind, data in entries:
        journal.append(kind, {k: v for k, v in data.items() if k not in ("preop_ids", "intraop_ids", "initial")})
    journal.close()
    with Session.open(old) as s:
        (stored,) = s.registrations()
        assert stored.preop_ids is None and stored.intraop_ids is None and stored.result.initial is None
    (reg,) = load_review(old).registrations
    assert reg.intraop_ids == truth.node_ids and reg.preop_ids == PREOP_IDS[:3]


def test_clock_figures_say_where_streams_end_and_how_far_nodes_are_from_fixes(recorded):
    path, truth = recorded
    figures = clock_figures(path)
    assert figures["ends_s"]["imu"] == pytest.approx((int(DURATION_S * 208) - 1) / 208, abs=1e-3)
    assert figures["ends_s"]["probe"] == pytest.approx((DURATION_S * FRAME_RATE_HZ - 1) / FRAME_RATE_HZ + CAMERA_LAG_S,
                                                       abs=1e-3)
    assert figures["end_spread_s"] == pytest.approx(abs(figures["ends_s"]["probe"] - figures["ends_s"]["imu"]), abs=2e-3)
    assert figures["max_frame_gap_s"] == pytest.approx((LOST_FRAMES[-1] + 2 - LOST_FRAMES[0]) / FRAME_RATE_HZ, abs=1e-3)
    # nodes at 1.5, 4.2 and 6.5 s, fixes every 1/30 s: at most half a period from one
    assert figures["nodes"] == 3 and figures["max_node_to_fix_s"] <= 0.5 / FRAME_RATE_HZ + 1e-3
