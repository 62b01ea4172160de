"""``snreg imu simulate --still --parent PID``: the demo rig's IMU process, and that it never outlives the app."""

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import serial

from conftest import poll

from snreg.imu.protocol import StreamDecoder


def ended(pid: int) -> bool:
    """The process is gone or a zombie nobody has reaped yet."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def test_the_still_simulator_streams_level_samples_and_stops_when_its_parent_ends(tmp_path):
    link = tmp_path / "imu"
    # a stand-in for the app: starts the simulator as its child, then ends (as a killed app would)
    parent = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import os, subprocess, sys, time
        child = subprocess.Popen([sys.executable, "-m", "snreg.cli", "imu", "simulate", "--still",
                                  "--port-link", {str(link)!r}, "--parent", str(os.getpid())],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        print(child.pid, flush=True)
        time.sleep(float(sys.stdin.readline()))
    """)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    child_pid = int(parent.stdout.readline())
    assert poll(link.exists)
    with serial.Serial(str(link), 230400, timeout=0.2) as port:
        decoder = StreamDecoder()
        samples = []
        end = time.monotonic() + 15.0          # a first start on a loaded machine compiles and imports for seconds
        while time.monotonic() < end and len(samples) < 20:
            samples += [item for item in decoder.feed(port.read(4096), time.perf_counter_ns()) if hasattr(item, "accel_g")]
    assert len(samples) >= 20
    assert all(abs(s.accel_g[2] - 1.0) < 0.05 and max(abs(s.gyro_dps)) < 1.0 for s in samples)   # level and still
    parent.communicate("0\n", timeout=10)                      # the "app" ends
    assert poll(lambda: ended(child_pid))
    assert not link.exists()                                   # it cleaned up as on Ctrl-C


def test_the_still_simulator_holds_the_attitude_it_is_given(tmp_path):
    """``--attitude``: the demo rig's endoscope held as it lies in the patient, the accelerometer reading up."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    link = tmp_path / "imu"
    child = subprocess.Popen([sys.executable, "-m", "snreg.cli", "imu", "simulate", "--still", "--attitude=0,8,-95",
                              "--port-link", str(link)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert poll(link.exists)
        with serial.Serial(str(link), 230400, timeout=0.2) as port:
            decoder, samples, end = StreamDecoder(), [], time.monotonic() + 15.0
            while time.monotonic() < end and len(samples) < 20:
                samples += [item for item in decoder.feed(port.read(4096), time.perf_counter_ns())
                            if hasattr(item, "accel_g")]
    finally:
        child.terminate()          # how it ends on SIGTERM: the test above (its parent's end)
        try:
            child.wait(10)
        except subprocess.TimeoutExpired:      # once in CI, not reproduced (12 runs beside four hogs): not this test's
            child.kill()                       # subject, and a child left running would outlive the suite
            child.wait(10)
    up = Rotation.from_euler("ZYX", [0.0, 8.0, -95.0], degrees=True).inv().apply([0.0, 0.0, 1.0])
    assert len(samples) >= 20 and all(np.linalg.norm(np.asarray(s.accel_g) - up) < 0.05 for s in samples)
