"""A writer killed with SIGKILL at a random moment loses no node whose add_intraop_node had returned."""

import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from snreg.session import Session
from snreg.session.export import recover
from snreg.session.schema import SessionError

KILLS = 60
SEED = 20240611

WRITER = r"""
import sys, time
import numpy as np
from snreg.session import Session
rng = np.random.default_rng(int(sys.argv[2]))
snapshot = (rng.random((24, 32, 3)) * 255).astype(np.uint8)
with Session.create(sys.argv[1], case_id="kill-test", stream_flush_s=0.005) as s:
    print("ready", flush=True)
    for k in range(1, 100000):
        n = int(rng.integers(1, 300))
        t = np.arange(n, dtype=np.int64) + time.time_ns()
        s.append_imu(t, t, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
        s.append_probe(t[:5], t[:5], np.ones((5, 3)), np.ones((5, 3)), np.ones((5, 3)), np.ones(5))
        s.append_frames(t[:3], t[:3], np.arange(3))
        s.add_intraop_node(f"SN{k}", "OBT R", [k, 2.0 * k, -k], xyz_camera=[0, 0, k], n_frames=k,
                           left_jpeg=snapshot, right_jpeg=snapshot)
        print(f"SN{k}", flush=True)
"""


def _kill_run(tmp_path, k):
    """One writer killed after a seeded random delay; returns (path, node ids printed)."""
    rng = np.random.default_rng(SEED + k)
    path = tmp_path / f"s{k}.h5"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(k)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    if rng.random() < 0.1:           # now and then during start-up and create
        time.sleep(rng.uniform(0.0, 0.4))
    else:
        assert proc.stdout.readline() == "ready\n"
        time.sleep(rng.uniform(0.0, 0.25))
    os.kill(proc.pid, signal.SIGKILL)
    out = proc.stdout.read()
    proc.wait()
    printed = [line for line in out.split("\n")[:-1] if line.startswith("SN")]   # complete lines only
    return path, printed


def _check(path, printed):
    with Session.open(path) as session:
        nodes = session.intraop_nodes()
    assert set(printed) <= set(nodes.ids)
    for node_id in printed:
        k = int(node_id[2:])
        assert np.allclose(nodes.xyz[nodes.ids.index(node_id)], [k, 2.0 * k, -k])
    return session.damaged


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX SIGKILL")
def test_every_returned_node_survives_sigkill(tmp_path):
    with ThreadPoolExecutor(max_workers=4) as pool:
        runs = list(pool.map(lambda k: _kill_run(tmp_path, k), range(KILLS)))
    checked, damaged = 0, 0
    for k, (path, printed) in enumerate(runs):
        if not printed:               # killed before any node returned: it may open or refuse, clearly
            try:
                _check(path, printed)
            except SessionError:
                pass
            continue
        damaged += _check(path, printed)
        checked += len(printed)
        if k % 5 == 0:                # recovery gives a clean file with the same nodes
            recover(path)
            assert _check(path, printed) is False
    print(f"{KILLS} kills, {checked} nodes checked, {damaged} HDF5 files damaged")
    assert checked > KILLS            # the kills landed inside the writing loop
