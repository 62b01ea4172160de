"""A writer killed with SIGKILL at a random moment loses no node whose add_intraop_node had returned, and a kill during a
re-expression leaves every node all old or all new.

The kill moments are set by the writer's progress, not by wall time: the killer waits for a random number of the
writer's lines (or its "creating" line, to land inside ``Session.create``), then a short random delay. On a heavily
loaded machine a fixed delay after start-up often ended the writer before it had stored anything, and the writer
itself crashed whenever it drew fewer IMU rows than the 5 probe rows it appends, so the check that the kills land
inside the writing loop failed (issue 12) although no node was lost. Each run now checks that its writer was killed
after the nodes waited for, so a writer that dies on its own fails the test instead of thinning it.
"""

import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from snreg.session import Session
from snreg.session.recovery import recover
from snreg.session.schema import SessionError

KILLS = 60
SEED = 20240611

WRITER = r"""
import sys, time
import numpy as np
from snreg.session import Session
rng = np.random.default_rng(int(sys.argv[2]))
snapshot = (rng.random((24, 32, 3)) * 255).astype(np.uint8)
print("creating", flush=True)
with Session.create(sys.argv[1], case_id="kill-test", stream_flush_s=0.005) as s:
    print("ready", flush=True)
    for k in range(1, 100000):
        n = int(rng.integers(5, 300))       # at least the 5 probe rows below (fewer crashed the writer)
        t = np.arange(n, dtype=np.int64) + time.time_ns()
        s.append_imu(t, t, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
        s.append_probe(t[:5], t[:5], np.ones((5, 3)), np.ones((5, 3)), np.ones((5, 3)), np.ones(5))
        s.append_frames(t[:3], t[:3], np.arange(3))
        s.add_intraop_node(f"SN{k}", "OBT R", [k, 2.0 * k, -k], xyz_camera=[0, 0, k], n_frames=k,
                           left_jpeg=snapshot, right_jpeg=snapshot)
        print(f"SN{k}", flush=True)
"""


def _kill(proc, wait_for: str, lines: int, delay_s: float) -> list[str]:
    """Read the writer's lines until ``lines`` of them start with ``wait_for``, sleep ``delay_s``, SIGKILL it;
    returns every complete line it printed."""
    seen, out = 0, []
    while seen < lines:
        line = proc.stdout.readline()
        if not line:
            break
        out.append(line.rstrip("\n"))
        seen += line.startswith(wait_for)
    time.sleep(delay_s)
    os.kill(proc.pid, signal.SIGKILL)
    rest = proc.stdout.read()
    proc.wait()
    return out + rest.split("\n")[:-1]                 # complete lines only


def _kill_run(tmp_path, k):
    """One writer killed at a seeded random point of its progress; returns (path, node ids printed, nodes waited for)."""
    rng = np.random.default_rng(SEED + k)
    path = tmp_path / f"s{k}.h5"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(k)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    if rng.random() < 0.1:           # now and then inside Session.create
        lines = _kill(proc, "creating", 1, rng.uniform(0.0, 0.05))
        waited = 0
    else:
        waited = int(rng.integers(1, 6))
        lines = _kill(proc, "SN", waited, rng.uniform(0.0, 0.03))
    return path, [line for line in lines if line.startswith("SN")], waited


def _check(path, printed):
    with Session.open(path) as session:
        nodes = session.intraop_nodes()
    assert set(printed) <= set(nodes.ids)
    for node_id in printed:
        k = int(node_id[2:])
        assert np.allclose(nodes.xyz[nodes.ids.index(node_id)], [k, 2.0 * k, -k])
    return session.damaged


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX SIGKILL")
def test_every_returned_node_survives_sigkill(tmp_path):
    with ThreadPoolExecutor(max_workers=4) as pool:
        runs = list(pool.map(lambda k: _kill_run(tmp_path, k), range(KILLS)))
    checked, damaged = 0, 0
    for k, (path, printed, waited) in enumerate(runs):
        assert len(printed) >= waited                 # the writer was killed after those nodes, not before
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


REEXPRESS_KILLS = 12
REEXPRESSER = r"""
import sys
import numpy as np
from scipy.spatial.transform import Rotation
from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration, camera_to_trocar
from snreg.session import Session, calibration_version
from snreg.session.schema import stereo_to_dict
from snreg.workflow.chain_change import reexpress
stereo, chains = thesis_calibration(), [ChainCalibration.manual(), ChainCalibration.manual(trocar_camera_mm=171.5)]
rng = np.random.default_rng(int(sys.argv[2]))
with Session.create(sys.argv[1], case_id="kill-reexpress") as s:
    for k in range(6):
        camera, turn = rng.uniform([-30, -20, 70], [30, 20, 130]), Rotation.random(random_state=k).as_matrix()
        s.add_intraop_node(f"SN{k + 1}", "", camera_to_trocar(chains[0], turn, camera), xyz_camera=camera,
                           earth_from_imu=turn, stereo_version=calibration_version(stereo_to_dict(stereo)),
                           chain_version=calibration_version(chains[0].to_dict()))
    print("stored", flush=True)
    for k in range(1, 100000):
        reexpress(s, stereo, chains[k % 2])
        print(f"R{k}", flush=True)
"""


def _reexpress_kill_run(tmp_path, k):
    rng = np.random.default_rng(SEED + 1000 + k)
    path = tmp_path / f"r{k}.h5"
    proc = subprocess.Popen([sys.executable, "-c", REEXPRESSER, str(path), str(k)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    waited = int(rng.integers(1, 6))
    lines = _kill(proc, "R", waited, rng.uniform(0.0, 0.03))
    return path, sum(line.startswith("R") for line in lines), waited


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX SIGKILL")
def test_a_kill_during_reexpression_loses_nothing(tmp_path):
    """Every node survives, all under one chain (never half re-expressed), at the place that chain maps its recorded
    camera tip, and no re-expression that had returned is undone."""
    from snreg.chain import ChainCalibration, camera_to_trocar
    from snreg.session import calibration_version

    chains = [ChainCalibration.manual(), ChainCalibration.manual(trocar_camera_mm=171.5)]
    chain_of = {calibration_version(chain.to_dict()): chain for chain in chains}
    with ThreadPoolExecutor(max_workers=4) as pool:
        runs = list(pool.map(lambda k: _reexpress_kill_run(tmp_path, k), range(REEXPRESS_KILLS)))
    for k, (path, returned, waited) in enumerate(runs):
        assert returned >= waited
        if k % 4 == 0:
            recover(path)
        with Session.open(path) as session:
            nodes = session.intraop_records()
            done = len(session.events("nodes_reexpressed"))
        assert [node.id for node in nodes] == [f"SN{j}" for j in range(1, 7)]
        assert done in (returned, returned + 1)            # the one under way when killed: all or nothing
        [version] = {node.chain_version for node in nodes}
        assert chain_of[version] is chains[done % 2]
        for node in nodes:
            expected = camera_to_trocar(chain_of[version], node.earth_from_imu, node.xyz_camera)
            np.testing.assert_allclose(node.xyz_trocar, expected, atol=1e-9)
