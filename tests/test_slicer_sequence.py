"""``snreg session export --format slicer-sequence``: probe poses in the trocar frame from the stored probe and IMU
streams and the session's chain, read back with a reader written from the file format (tests/sequence_metafile_reader.py)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sequence_metafile_reader import SLICER_LINE_LIMIT, read_sequence_metafile, slicer_index_values, transforms

from snreg.chain import ChainCalibration, camera_from_probe, trocar_from_probe
from snreg.cli import main
from snreg.errors import SessionError
from snreg.imu.fusion import Fusion
from snreg.imu.protocol import DEFAULT_ODR_HZ, ImuSample
from snreg.session import Session
from snreg.session.slicer_sequence import probe_poses, seconds_text, write_slicer_sequence

TILT = Rotation.from_euler("ZYX", [0.0, 20.0, -12.0], degrees=True)     # earth_from_imu: pitched and rolled, held still
T0_NS = 5_000_000_000_123
PERIOD_NS = round(1e9 / DEFAULT_ODR_HZ)


def imu_samples(n: int, rng) -> list[ImuSample]:
    """A still, tilted IMU: gravity seen in the sensor frame, a little noise, zero rate; float32 values, as stored."""
    gravity = TILT.inv().apply([0.0, 0.0, 1.0])
    accel = (gravity + rng.normal(0, 1e-3, (n, 3))).astype(np.float32)
    gyro = rng.normal(0, 0.02, (n, 3)).astype(np.float32)
    return [ImuSample(T0_NS + k * PERIOD_NS, k * PERIOD_NS // 1000, accel[k], gyro[k]) for k in range(n)]


@pytest.fixture
def recorded(tmp_path, rng):
    """A session with 10 s of tilted IMU samples and 40 probe fixes in the last 4 s, each at an IMU sample's time."""
    samples = imu_samples(int(10 * DEFAULT_ODR_HZ), rng)
    chain = ChainCalibration.manual()
    picks = np.linspace(len(samples) * 6 // 10, len(samples) - 1, 40).astype(int)
    tips = rng.uniform([-40, -20, 60], [40, 20, 120], (len(picks), 3))
    axes = rng.normal([0.2, -0.5, -0.8], 0.1, (len(picks), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    path = tmp_path / "tilted.h5"
    with Session.create(path, case_id="seq-1", stream_flush_s=0) as session:
        session.set_calibration(chain=chain)
        session.append_imu(np.array([s.t_host_ns for s in samples]), np.array([s.t_device_us for s in samples]) * 1000,
                           np.array([s.accel_g for s in samples]), np.array([s.gyro_dps for s in samples]))
        t_probe = np.array([samples[k].t_host_ns for k in picks])
        session.append_probe(t_probe, t_probe, tips, tips + 30 * axes, axes, np.ones(len(picks)))
    # the orientation the live filter had after each picked sample, sample by sample as the acquisition fuses
    fusion, orientation = Fusion(DEFAULT_ODR_HZ), {}
    for k, sample in enumerate(samples):
        fusion.advance(sample)
        orientation[k] = fusion.earth_from_sensor
    truth = np.stack([trocar_from_probe(chain, orientation[k], camera_from_probe(tip, axis))
                      for k, tip, axis in zip(picks, tips.astype(np.float32), axes.astype(np.float32))])
    return path, t_probe, truth, [orientation[k] for k in picks]


def test_the_export_holds_the_probe_poses_at_the_fused_imu_orientation(recorded, tmp_path):
    path, t_probe, truth, orientations = recorded
    tilt = [np.degrees((Rotation.from_matrix(o) * TILT.inv()).magnitude()) for o in orientations]
    assert max(tilt) < 1.0                           # the filter has settled on the tilt: a non-trivial orientation
    assert main(["session", "export", str(path), "--format", "slicer-sequence", "-o", str(tmp_path / "out")]) == 0
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["ProbeTipToTrocar.seq.mha"]     # no leftovers
    sequence = read_sequence_metafile(tmp_path / "out" / "ProbeTipToTrocar.seq.mha")
    times, matrices, statuses = transforms(sequence, "ProbeTipToTrocar")
    np.testing.assert_allclose(matrices, truth, atol=1e-6)
    np.testing.assert_allclose(times, t_probe / 1e9, rtol=0, atol=1e-9)
    assert statuses == ["OK"] * len(t_probe)
    assert [int(frame["Timestamp"].replace(".", "")) for frame in sequence.frames] == list(t_probe)    # exact ns
    assert sequence.longest_line < SLICER_LINE_LIMIT
    assert len(set(slicer_index_values(sequence))) == len(t_probe)        # one Slicer index value per fix


def test_between_imu_samples_the_orientation_is_interpolated(recorded):
    path, t_probe, truth, _ = recorded
    poses = probe_poses(path)
    np.testing.assert_array_equal(poses.t_host_ns, t_probe)
    assert "fused" in poses.imu
    np.testing.assert_allclose(poses.trocar_from_probe, truth, atol=1e-6)


def test_sessions_without_a_chain_or_probe_fixes_are_one_sentence(tmp_path, capsys):
    bare = tmp_path / "bare.h5"
    with Session.create(bare, case_id="seq-2"):
        pass
    with pytest.raises(SessionError, match="no chain calibration"):
        write_slicer_sequence(bare, tmp_path / "out")
    with Session.create(tmp_path / "idle.h5", case_id="seq-3") as session:
        session.set_calibration(chain=ChainCalibration.manual())
    assert main(["session", "export", str(tmp_path / "idle.h5"), "--format", "slicer-sequence",
                 "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "holds no probe fixes" in err and len(err.strip().splitlines()) == 1


def test_host_times_are_written_as_exact_decimal_seconds():
    assert seconds_text(5_000_000_000_123) == "5000.000000123"
    assert seconds_text(999) == "0.000000999" and seconds_text(-1_500_000_000) == "-1.500000000"
