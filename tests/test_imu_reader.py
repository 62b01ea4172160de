"""The IMU stream end to end through real pseudo-terminals and pyserial: simulator, reader, replay, commands."""

import argparse
import csv
import json
import os
import signal
import subprocess
import sys
import tty
import types
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import poll

from snreg.cli import main
from snreg.cli.imu import add_imu_parser
from snreg.demo.imu_motion import MotionProfile, protractor_profile, read_motion_file, rotate, still
from snreg.demo.imu_simulator import CsvReplay, Faults, ImuSimulator, SensorModel, SimulatedPort
from snreg.errors import UserError
from snreg.imu import reader as imu_reader_module
from snreg.imu.fusion import Fusion, fuse_arrays
from snreg.imu.protocol import ImuSample, StreamCounts, format_line, parse_line
from snreg.imu.reader import ImuPortError, ImuState, SerialImuReader

XIO_CSV = Path(__file__).resolve().parent / "data" / "imu" / "fusion_sensor_data.csv"
EXACT = SensorModel(0.0, 0.0, 0.0, None, None)          # noise-free, unquantised, no bias


def test_the_simulated_stream_arrives_complete_and_in_order():
    sim = ImuSimulator(protractor_profile(rate_dps=100.0, hold_s=0.1, start_s=0.1), rate_hz=4000, n_samples=3000, seed=3)
    got = []
    with SimulatedPort(sim) as port:
        reader = SerialImuReader(port.port, on_sample=got.append, queue_size=10)
        with reader:                                          # the port is open before the simulator writes
            port.start()
            assert poll(lambda: port.finished.is_set() and reader.counts.samples == sim.sent.samples)
            assert reader.state is ImuState.STREAMING and reader.problem == ""
            assert reader.info.odr_hz == 4000 and reader.rate_hz == 4000
    assert reader.state is ImuState.STOPPED
    assert reader.counts == sim.sent == StreamCounts(samples=3000, corrupt=0, dropped=0)
    expected = sim.readings(3000)
    np.testing.assert_array_equal([s.t_device_us for s in got], expected.t_device_us)
    np.testing.assert_array_equal(np.array([s.accel_g for s in got]), np.round(expected.accel_g, 6))
    np.testing.assert_array_equal(np.array([s.gyro_dps for s in got]), np.round(expected.gyro_dps, 6))
    assert np.all(np.diff([s.t_host_ns for s in got]) >= 0)
    assert reader.queue.qsize() == 10 and reader.overflow == 2990


def test_a_fuzzed_stream_gives_the_true_corrupt_and_dropped_counts_across_the_clock_wrap():
    sim = ImuSimulator(rate_hz=4000, n_samples=4000, seed=11, faults=Faults(dropout_rate=0.03, garbage_rate=0.06),
                       start_us=(1 << 32) - 500_000)
    got = []
    with SimulatedPort(sim) as port, SerialImuReader(port.port, on_sample=got.append) as reader:
        port.start()
        assert poll(lambda: port.finished.is_set() and reader.counts.samples == sim.sent.samples)
        assert reader.state is ImuState.STREAMING
    assert reader.counts == sim.sent
    assert reader.last_corrupt.reason in {"not a protocol line", "no $...*checksum frame (truncated?)", "checksum mismatch"}
    assert sim.sent.corrupt > 150 and sim.sent.dropped > 200 and sim.sent.samples > 3500
    times = np.array([s.t_device_us for s in got])
    assert times.min() < 10_000 and times.max() > (1 << 32) - 10_000      # the device clock wrapped


def test_unplug_then_replug_behind_the_same_link(tmp_path):
    link = str(tmp_path / "imu")
    states = []
    first = SimulatedPort(ImuSimulator(rate_hz=1000, seed=1), port_link=link).start()
    reader = SerialImuReader(link, on_state=lambda state, problem: states.append(state), retry_interval_s=0.05)
    with reader:
        assert poll(lambda: reader.counts.samples > 50)
        first.stop()                                          # unplug: the pty closes and the link goes
        assert poll(lambda: reader.state is ImuState.DISCONNECTED)
        assert not os.path.lexists(link)
        assert reader.problem == f"the IMU port {link} went away; reconnect the sensor, retrying every 0.05 s"
        before = reader.counts.samples
        second = SimulatedPort(ImuSimulator(rate_hz=1000, seed=2), port_link=link).start()
        try:
            assert poll(lambda: reader.state is ImuState.STREAMING and reader.counts.samples > before + 50)
        finally:
            reader.stop()
            second.stop()
    assert states == [ImuState.CONNECTING, ImuState.STREAMING, ImuState.DISCONNECTED, ImuState.CONNECTING,
                      ImuState.STREAMING, ImuState.STOPPED]
    assert reader.counts.dropped == 0
    assert reader.counts.corrupt <= 1       # at most the line the reconnect cut (pyserial flushes on open)


def test_silence_makes_the_stream_stale_and_data_revives_it():
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        reader = SerialImuReader(os.ttyname(slave), rate_hz=1000, stale_after_s=0.2)
        with reader:
            assert poll(lambda: reader.state is ImuState.STALE)    # open but silent
            os.write(master, b"".join(format_line(1000 * k, [0, 0, 1], [0, 0, 0]) for k in range(5)))
            assert poll(lambda: reader.state is ImuState.STREAMING)
            assert poll(lambda: reader.state is ImuState.STALE)
            assert "no valid IMU sample for 0.2 s" in reader.problem        # the reader's own clock, not the test's
            os.write(master, format_line(5000, [0, 0, 1], [0, 0, 0]))
            assert poll(lambda: reader.state is ImuState.STREAMING)
        assert reader.counts == StreamCounts(samples=6, corrupt=0, dropped=0)
    finally:
        os.close(master)
        os.close(slave)


def test_a_burst_of_lines_is_decoded_in_one_go_and_yields_every_sample():
    """A device sends lines whole: the reader decodes a burst that arrived at once in one delivery (it once decoded the
    first byte alone, then the rest), with one host stamp, and yields every sample of it in order."""
    bursts = [b"".join(format_line(5000 * (10 * b + k), [0, 0, 1], [0, 0, k]) for k in range(10)) for b in range(3)]
    master, slave = os.openpty()
    tty.setraw(slave)
    got, fed = [], []
    try:
        reader = SerialImuReader(os.ttyname(slave), rate_hz=200, on_sample=got.append)
        feed = reader._decoder.feed
        reader._decoder.feed = lambda data, t_ns: fed.append(data) or feed(data, t_ns)     # noqa: SLF001
        with reader:
            assert poll(lambda: reader.state is ImuState.CONNECTING)
            for n, burst in enumerate(bursts, 1):
                os.write(master, burst)
                assert poll(lambda n=n: reader.counts.samples == 10 * n)
    finally:
        os.close(master)
        os.close(slave)
    assert fed == bursts
    assert [s.t_device_us for s in got] == [5000 * k for k in range(30)] and reader.counts.corrupt == 0
    assert [len({s.t_host_ns for s in got[10 * b:10 * b + 10]}) for b in range(3)] == [1, 1, 1]


def test_a_port_that_cannot_be_opened_says_what_to_do(tmp_path):
    with pytest.raises(ImuPortError, match="Cannot open the IMU port .*check that the IMU is plugged in") as info:
        SerialImuReader(str(tmp_path / "ttyACM9")).start()
    assert isinstance(info.value, ValueError)


def _replay_through_a_pty(replay, speed):
    got = []
    with SimulatedPort(replay, speed=speed) as port, SerialImuReader(port.port, on_sample=got.append) as reader:
        port.start()
        assert poll(lambda: port.finished.is_set() and reader.counts.samples == len(replay.readings.t_s))
    assert reader.counts.corrupt == 0
    return got


def test_replay_keeps_the_recorded_values_unclipped(tmp_path):
    path = tmp_path / "rec.csv"
    path.write_text("Time (s),Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s),Accelerometer X (g),"
                    "Accelerometer Y (g),Accelerometer Z (g),Magnetometer X (uT)\n"
                    "0,365.3081,-0.1517251,1.5e-07,0.001015204,-0.02,0.9970807,15.3\n"
                    "0.01,-250,0,0,-4.5,0,1,15.3\n0.02,0,0,0,0,0,1,15.3\n", encoding="utf-8")
    replay = CsvReplay(path)
    assert replay.decimals == 9 and replay.rate_hz == pytest.approx(100.0)
    got = _replay_through_a_pty(replay, speed=1.0)
    np.testing.assert_array_equal([s.gyro_dps for s in got], [[365.3081, -0.1517251, 1.5e-07], [-250, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal([s.accel_g for s in got], [[0.001015204, -0.02, 0.9970807], [-4.5, 0, 1], [0, 0, 1]])
    assert [s.t_device_us for s in got] == [0, 10_000, 20_000]


@pytest.mark.slow
def test_replay_of_the_xio_recording_reproduces_the_file():
    replay = CsvReplay(XIO_CSV)
    got = _replay_through_a_pty(replay, speed=200.0)
    with open(XIO_CSV, newline="", encoding="utf-8") as f:
        rows = np.array([[float(v) for v in row[:7]] for row in list(csv.reader(f))[1:]])
    assert len(got) == len(rows) == 13514
    np.testing.assert_array_equal([s.gyro_dps for s in got], rows[:, 1:4])           # exact: the file's precision
    np.testing.assert_array_equal([s.accel_g for s in got], rows[:, 4:7])
    np.testing.assert_array_equal([s.t_device_us for s in got], np.round(rows[:, 0] * 1e6))
    assert np.abs(rows[:, 1:4]).max() > 300                                           # beyond +-125 deg/s, kept
    # ... and fused as they arrive, the angles equal imufusion run on the file directly
    live = Fusion(replay.rate_hz, gyroscope_range_dps=2000.0, initial_bias_period_s=0)
    angles = np.array([live.update(sample) for sample in got])
    direct = fuse_arrays(rows[:, 0], rows[:, 1:4], rows[:, 4:7], gyroscope_range_dps=2000.0, initial_bias_period_s=0)
    assert np.abs((angles - direct + 180.0) % 360.0 - 180.0).max() < 1e-3


def test_a_level_sensor_at_rest_reads_gravity_its_bias_and_datasheet_noise():
    sim = ImuSimulator(rate_hz=208, seed=4)
    r = sim.readings(20_000)
    accel_sigma, gyro_sigma = 75e-6 * np.sqrt(104), 3.8e-3 * np.sqrt(104)             # density * sqrt(ODR / 2)
    np.testing.assert_allclose(r.accel_g.mean(axis=0), [0, 0, 1], atol=4 * accel_sigma / np.sqrt(20_000) + 1e-4)
    np.testing.assert_allclose(r.gyro_dps.mean(axis=0), sim.gyro_bias_dps, atol=4 * gyro_sigma / np.sqrt(20_000) + 3e-3)
    np.testing.assert_allclose(r.accel_g.std(axis=0), accel_sigma, rtol=0.05)
    np.testing.assert_allclose(r.gyro_dps.std(axis=0), gyro_sigma, rtol=0.05)
    assert np.all(np.abs(sim.gyro_bias_dps) <= 0.5) and not np.allclose(sim.gyro_bias_dps, ImuSimulator(seed=5).gyro_bias_dps)
    for values, lsb in ((r.accel_g, 0.122e-3), (r.gyro_dps, 4.375e-3)):              # LSM6DSOX LSBs at +-4 g, +-125 dps
        np.testing.assert_allclose(values / lsb, np.round(values / lsb), atol=1e-6)
    np.testing.assert_array_equal(np.diff(r.t_device_us[:5]), [4808, 4807, 4808, 4808])


def test_gyro_integrates_to_the_true_orientation_and_accel_is_gravity_in_the_sensor_frame():
    profile = MotionProfile([still(0.2), rotate((0, 0, 1), 90, 45), rotate((1, 1, 0), -30, 20, smooth=False), still(0.2)],
                            initial=Rotation.from_euler("x", 10, degrees=True))
    sim = ImuSimulator(profile, rate_hz=1000, sensor=EXACT, n_samples=int(profile.duration_s * 1000) + 1)
    r = sim.readings(sim.n_samples)
    truth = sim.true_orientation(r.t_device_us)
    np.testing.assert_allclose(r.accel_g, truth.inv().apply([0, 0, 1]), atol=1e-12)
    estimate = profile.initial
    for k in range(len(r.t_s) - 1):                                                 # trapezoid in the body frame
        estimate = estimate * Rotation.from_rotvec(np.radians(r.gyro_dps[k] + r.gyro_dps[k + 1]) / 2 * 1e-3)
    end = Rotation.from_rotvec(np.radians(-30) * np.array([1, 1, 0]) / np.sqrt(2)) * Rotation.from_euler("z", 90, degrees=True)
    assert np.degrees((end * profile.initial * truth[-1].inv()).magnitude()) < 1e-9
    assert np.degrees((estimate * truth[-1].inv()).magnitude()) < 0.05


def test_profiles_hold_at_the_end_or_repeat():
    spin = MotionProfile([rotate((0, 0, 1), 90, 90, smooth=False)], repeat=True)
    np.testing.assert_allclose(spin.orientation(2.5).as_euler("ZYX", degrees=True)[0], [-135, 0, 0], atol=1e-9)
    np.testing.assert_allclose(spin.angular_velocity_dps([0.5, 7.5]), [[0, 0, 90], [0, 0, 90]])
    held = MotionProfile([rotate((0, 1, 0), 20, 10)])
    assert held.orientation(50.0)[0].approx_equal(Rotation.from_euler("y", 20, degrees=True))
    np.testing.assert_array_equal(held.angular_velocity_dps([-1.0, 50.0]), np.zeros((2, 3)))
    protractor = protractor_profile()
    assert protractor.duration_s == pytest.approx(4 + 2 * sum(2 * a / 5 + 2 * 2 for a in (1, 5, 10)))
    assert protractor.orientation(protractor.duration_s)[0].magnitude() < 1e-12     # it returns to the start
    assert np.degrees(protractor.orientation(4 + 0.2 + 1.0)[0].magnitude()) == pytest.approx(1.0)


def test_a_profile_holds_its_first_pose_before_time_0_and_round_trips_through_its_file(tmp_path):
    """A program hands its motion to the simulator process as a file; before the motion's time 0 (the stream started
    early, its start set on the host clock) the sensor holds the first pose, also when the profile repeats."""
    start = Rotation.from_euler("ZYX", [0.0, 30.0, 120.0], degrees=True)
    axis = (0.3, 0.4, 0.5)
    profile = MotionProfile([still(0.5), rotate(axis, 12.0, 8.0), still(0.2), rotate(axis, -12.0, 8.0)], start,
                            repeat=True)
    assert profile.orientation([-3.0])[0].approx_equal(start)
    np.testing.assert_array_equal(profile.angular_velocity_dps([-3.0]), np.zeros((1, 3)))
    path = tmp_path / "motion.json"
    path.write_text(json.dumps(profile.to_dict()))
    again = read_motion_file(path)
    times = np.linspace(-1.0, 2 * profile.duration_s, 97)
    assert np.all(np.degrees((again.orientation(times) * profile.orientation(times).inv()).magnitude()) < 1e-9)
    np.testing.assert_allclose(again.angular_velocity_dps(times), profile.angular_velocity_dps(times), atol=1e-9)
    backwards = {**profile.to_dict(), "segments": [{"duration_s": -1, "axis": [0, 0, 1], "angle_deg": 0,
                                                    "smooth": True}]}
    for bad, words in (("[1, 2]", "not a motion profile"), ('{"segments": []', "not a motion file"),
                       (json.dumps(backwards), "positive duration")):
        path.write_text(bad)
        with pytest.raises(ValueError, match=words):
            read_motion_file(path)


def test_a_stream_started_before_the_motion_holds_still_until_it_starts():
    """``lines(motion_offset_s)``: the stream's time 0 lies that far into the motion (negative: before it)."""
    profile = MotionProfile([rotate((0, 0, 1), 30.0, 30.0)])
    sim = ImuSimulator(profile, rate_hz=100, sensor=EXACT, n_samples=400)
    samples = [parse_line(line) for _, line in sim.lines(-2.0)]
    gyro = np.array([s.gyro_dps for s in samples if isinstance(s, ImuSample)])
    assert np.all(gyro[:200] == 0.0) and gyro[200:300, 2].max() > 50.0 and np.all(gyro[300:] == 0.0)


def test_a_port_holds_the_motion_and_says_on_the_host_clock_when_it_starts():
    """Another program shows the motion in step (the surgery demo's frames): the port holds the first pose for
    ``hold_s`` after its stream starts and reports the motion's start on the host clock."""
    sim = ImuSimulator(MotionProfile([rotate((0, 0, 1), 20.0, 40.0)]), rate_hz=500, sensor=EXACT, n_samples=600)
    starts, got = [], []
    with SimulatedPort(sim, hold_s=0.5, on_start=starts.append) as port:
        with SerialImuReader(port.port, on_sample=got.append):
            port.start()
            assert poll(lambda: port.finished.is_set() and len(got) == 600)
    assert starts == [port.started_ns + 500_000_000]
    moving = [s for s in got if abs(s.gyro_dps[2]) > 0]
    assert 500_000 <= moving[0].t_device_us < 504_000 and moving[-1].t_device_us < 1_000_000
    assert 0 <= moving[0].t_host_ns - starts[0] < 200_000_000        # received when due (latency under load)


def test_the_range_clips_and_quantises_like_the_sensor():
    fast = MotionProfile([rotate((0, 0, 1), 200, 200, smooth=False)])
    for range_dps, expected in ((125, 32767 * 4.375e-3), (250, 200.0)):
        sensor = SensorModel(0.0, 0.0, 0.0, accel_range_g=4, gyro_range_dps=range_dps)
        r = ImuSimulator(fast, rate_hz=100, sensor=sensor, n_samples=50).readings(50)
        assert r.gyro_dps[10:40, 2] == pytest.approx(expected, abs=8.75e-3)
    with pytest.raises(ValueError, match="range"):
        SensorModel(gyro_range_dps=300)
    with pytest.raises(ValueError, match="fractions"):
        Faults(dropout_rate=0.6, garbage_rate=0.6)


def test_the_stream_is_deterministic_under_its_seed():
    def stream(seed):
        sim = ImuSimulator(protractor_profile(), rate_hz=500, n_samples=2000, seed=seed, faults=Faults(0.05, 0.05))
        return [line for _, line in sim.lines()], sim.sent
    assert stream(7) == stream(7)
    assert stream(7)[0] != stream(8)[0]
    lines, sent = stream(7)
    parsed = [parse_line(line) for line in lines]
    assert sum(isinstance(p, ImuSample) for p in parsed) == sent.samples


def _parser():
    parser = argparse.ArgumentParser(prog="snreg")
    add_imu_parser(parser.add_subparsers(dest="command", required=True))
    return parser


def _run(*argv):
    args = _parser().parse_args(list(argv))
    return args.func(args)


@pytest.mark.parametrize("as_json", [True, False])
def test_monitor_writes_angles_per_sample_and_a_summary(tmp_path, monkeypatch, capsys, as_json):
    class StubFusion:                         # the interface of snreg.imu.fusion.Fusion
        rates = []

        def __init__(self, sample_rate_hz):
            self.rates.append(sample_rate_hz)

        def update(self, sample):
            return float(sample.t_device_us % 360), 1.0, -2.0

    monkeypatch.setitem(sys.modules, "snreg.imu.fusion", types.SimpleNamespace(Fusion=StubFusion))
    sim = ImuSimulator(rate_hz=4000, n_samples=1200, seed=5, faults=Faults(0.02, 0.02), start_us=(1 << 32) - 100_000)
    with SimulatedPort(sim) as port:
        class ReaderThatStartsTheSimulator(SerialImuReader):
            def start(self):
                super().start()
                port.start()
                return self

        monkeypatch.setattr(imu_reader_module, "SerialImuReader", ReaderThatStartsTheSimulator)  # imported when run
        out = tmp_path / "angles.csv"
        assert _run("imu", "monitor", port.port, "--seconds", "0.6", "--csv", str(out), *["--json"] * as_json) == 0
    printed = capsys.readouterr().out
    if as_json:
        summary = json.loads(printed)
        assert summary == {"samples": sim.sent.samples, "corrupt": sim.sent.corrupt, "dropped": sim.sent.dropped}
    else:
        assert printed.startswith(f"{sim.sent.samples} samples, {sim.sent.corrupt} corrupt (last: ")
        assert f"{sim.sent.dropped} dropped; streaming" in printed
    assert StubFusion.rates[-1] == 4000.0
    with open(out, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == sim.sent.samples and list(rows[0]) == ["t_host_s", "t_device_s", "yaw", "pitch", "roll"]
    device_s = np.array([float(r["t_device_s"]) for r in rows])
    assert np.all(np.diff(device_s) > 0) and device_s[-1] > (1 << 32) / 1e6              # unwrapped
    assert all(float(r["t_host_s"]) >= 0 for r in rows) and {r["roll"] for r in rows} == {"-2.0000"}


@pytest.mark.parametrize("argv, message", [
    (["imu", "monitor", "/nonexistent/ttyACM0"], "Cannot open the IMU port"),
    (["imu", "monitor", "/dev/null", "--seconds", "0"], "--seconds"),
    (["imu", "monitor", "/dev/null", "--baud", "0"], "--baud"),
    (["imu", "simulate", "--rate", "-5"], "from 1 to 6667 Hz"),
    (["imu", "simulate", "--garbage", "1.5"], "fraction"),
    (["imu", "simulate", "--replay", "/nonexistent.csv"], "no such IMU CSV file"),
    (["imu", "simulate", "--replay", "x.csv", "--rate", "100"], "--rate does not apply"),
    (["imu", "simulate", "--port-link", "/nonexistent/dir/imu"], "cannot create the link"),
    (["imu", "simulate", "--still", "--motion", "m.json"], "--still and --motion each choose"),
    (["imu", "simulate", "--motion", "/nonexistent.json"], "no such motion file"),
    (["imu", "simulate", "--replay", "x.csv", "--hold", "3"], "do not apply to --replay"),
    (["imu", "simulate", "--hold", "-5"], "--hold"),
    (["imu", "simulate", "--epoch-file", "/nonexistent/dir/epoch"], "does not exist"),
])
def test_bad_input_is_one_line_and_exit_2(argv, message, capsys):
    try:
        status = main(argv)
    except SystemExit as stop:                      # argparse's own checks (types, ranges)
        status = stop.code
    err = capsys.readouterr().err
    assert status == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_simulate_refuses_to_replace_a_regular_file(tmp_path):
    target = tmp_path / "precious.txt"
    target.write_text("keep me")
    with pytest.raises(UserError, match="not a symlink"):
        _run("imu", "simulate", "--port-link", str(target))
    assert target.read_text() == "keep me"


def test_simulate_command_streams_until_killed_and_cleans_up(tmp_path):
    link = tmp_path / "snreg-imu"
    code = ("import argparse, sys\nfrom snreg.cli.imu import add_imu_parser\n"
            "p = argparse.ArgumentParser()\nadd_imu_parser(p.add_subparsers(dest='command', required=True))\n"
            "a = p.parse_args(sys.argv[1:])\nsys.exit(a.func(a))\n")
    proc = subprocess.Popen([sys.executable, "-c", code, "imu", "simulate", "--port-link", str(link), "--rate", "500",
                             "--seed", "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert str(link) in proc.stdout.readline()
        with SerialImuReader(str(link)) as reader:
            assert poll(lambda: reader.counts.samples > 100)
        assert reader.counts.corrupt == 0 and reader.counts.dropped == 0     # it started when the reader opened
        assert reader.info.odr_hz == 500
        proc.send_signal(signal.SIGTERM)             # handled like Ctrl-C (SIGINT may be ignored in background jobs)
        assert proc.wait(timeout=10) == 0, proc.stderr.read()
    finally:
        proc.kill()
    assert not os.path.lexists(link)
