"""Shared fixtures. Qt runs offscreen; every random process is seeded."""

import contextlib
import os
import tempfile

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# QSettings (recent files, window layout, devices) of the app under test never touch the user's own.
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="snreg-test-config-")

import numpy as np
import pytest


@pytest.fixture(autouse=True)
def _own_settings_per_test(tmp_path_factory):
    """Each test starts from empty app settings (remembered tab, window layout, devices), whatever ran before it."""
    import sys
    if "PySide6.QtCore" in sys.modules:
        from PySide6.QtCore import QSettings
        folder = str(tmp_path_factory.mktemp("settings"))
        for fmt in (QSettings.Format.NativeFormat, QSettings.Format.IniFormat):
            QSettings.setPath(fmt, QSettings.Scope.UserScope, folder)
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """A test marked ``realtime`` runs alone: under pytest-xdist it holds the suite's lock exclusively (its setup,
    module fixtures included, and its teardown), every other test holds it shared. Such a test drives a live feed at
    its own pace (the demo rig, a recording), and a live source skips the frames its consumer cannot take, as a camera
    does: beside another worker's CPU-bound tests its store windows did not fill and its nodes were not stored."""
    token = getattr(item.config, "workerinput", {}).get("testrunuid")
    if token is None:                                       # not under xdist: nothing runs beside it
        yield
        return
    import fcntl
    with open(os.path.join(tempfile.gettempdir(), f"snreg-suite-{token}.lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX if item.get_closest_marker("realtime") else fcntl.LOCK_SH)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


DEADLINE_FLOOR_MS = 30_000   # a wait's deadline only names a hang; it never measures speed (the suite runs loaded)


def holds(predicate) -> bool:
    """``predicate()`` as a plain bool, False while it cannot be evaluated yet (None indexed, a list still empty):
    a wait's predicate never throws, so a race can only make a wait longer, never fail it."""
    try:
        return bool(predicate())
    except Exception:
        return False


def poll(predicate, timeout_s: float = 30.0, interval_s: float = 0.01) -> bool:
    """Poll ``predicate`` (see ``holds``) until it holds or ``timeout_s`` passes; its last answer."""
    import time
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if holds(predicate):
            return True
        time.sleep(interval_s)
    return holds(predicate)


def shared_memory_segments() -> set[str]:
    """The names of the shared memory segments Python made on this machine (Linux: /dev/shm)."""
    from pathlib import Path
    return {p.name for p in Path("/dev/shm").glob("psm_*")} if Path("/dev/shm").is_dir() else set()


@pytest.fixture
def created_segments(monkeypatch) -> set[str]:
    """The names of the shared memory segments this process creates during the test (the recorder's, the tracking
    process's), to see none is left: not the machine's whole /dev/shm, where another test worker's segments come and
    go meanwhile."""
    from multiprocessing import shared_memory
    created: set[str] = set()
    make = shared_memory.SharedMemory.__init__

    def recording(self, name=None, create=False, size=0, **options):
        make(self, name, create, size, **options)
        if create:
            created.add(self.name.lstrip("/"))
    monkeypatch.setattr(shared_memory.SharedMemory, "__init__", recording)
    return created


@contextlib.contextmanager
def parent_to_kill(script: str, cwd):
    """A Python process running ``script`` with the repository on its path, standing for the app: yielded to read
    what it prints (text); on leaving, it is told (a line on its stdin) to SIGKILL itself and must have died so; it is
    killed in any case."""
    import signal
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    parent = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True, cwd=cwd, env={**os.environ, "PYTHONPATH": str(root)})
    try:
        yield parent
        parent.stdin.write("\n")
        parent.stdin.flush()
        assert parent.wait(30) == -signal.SIGKILL
    finally:
        parent.kill()


def process_gone(pid: int) -> bool:
    """The process ``pid`` ended and was waited for (no zombie left either)."""
    import os
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.fixture
def qtbot(qtbot):
    """pytest-qt's qtbot whose waits cannot be failed by a race: ``waitUntil``'s callback may only fail by
    AssertionError (anything else it raises counts as "not yet", chained to the timeout that names it), a predicate's
    answer counts as a bool, and every wait that fails on its deadline waits at least DEADLINE_FLOOR_MS."""
    wait_until, wait_signal, wait_signals = qtbot.waitUntil, qtbot.waitSignal, qtbot.waitSignals

    def not_yet_unless_asserting(callback):
        def checked():
            try:
                answer = callback()
            except AssertionError:
                raise
            except Exception as error:
                raise AssertionError(f"not yet: {type(error).__name__}: {error}") from error
            return None if answer is None else bool(answer)
        return checked

    def waitUntil(callback, *, timeout: int = 5000):
        __tracebackhide__ = True
        return wait_until(not_yet_unless_asserting(callback), timeout=max(timeout, DEADLINE_FLOOR_MS))

    def deadline(timeout: int, raising) -> int:
        # a wait that does not raise is a negative check (assertNotEmitted's "nothing within wait ms"): its time is
        # its meaning, so only a raising wait gets the floor
        return timeout if raising is False else max(timeout, DEADLINE_FLOOR_MS)

    def waitSignal(signal=None, *, timeout: int = 5000, raising=None, **kwargs):
        return wait_signal(signal, timeout=deadline(timeout, raising), raising=raising, **kwargs)

    def waitSignals(signals=None, *, timeout: int = 5000, raising=None, **kwargs):
        return wait_signals(signals, timeout=deadline(timeout, raising), raising=raising, **kwargs)

    qtbot.waitUntil = qtbot.wait_until = waitUntil
    qtbot.waitSignal = qtbot.wait_signal = waitSignal
    qtbot.waitSignals = qtbot.wait_signals = waitSignals
    return qtbot


@pytest.fixture
def panel(qtbot):
    """The registration panel (offscreen), its workers waited for at the end; a test file may define its own."""
    from snreg_gui.registration.panel import RegistrationPanel

    widget = RegistrationPanel()
    qtbot.addWidget(widget)
    yield widget
    widget.shutdown()


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def pelvic_nodes():
    """Six well-separated nodes (mm) spread like a pelvic SN pattern, with station labels."""
    xyz = np.array([[-55.0, 20.0, 30.0], [-45.0, 42.0, 8.0], [-47.0, 78.0, 50.0],
                    [52.0, 18.0, 35.0], [44.0, 45.0, 12.0], [12.0, 100.0, 72.0]])
    labels = ["EXT R", "OBT R", "INT R", "EXT L", "OBT L", "SAC L"]
    return xyz, labels


def shown(points) -> tuple[list, np.ndarray]:
    """The names and (N, 3) positions of a received POINT message's points that Slicer shows (alpha above 0): an
    empty list goes as one hidden point (snreg.workflow.live_messages.point_list)."""
    keep = [k for k, rgba in enumerate(points.rgba_colors) if rgba[3] > 0]
    return [points.names[k] for k in keep], np.array([points.positions[k] for k in keep], dtype=float).reshape(-1, 3)


class RecordingIgtlClient:
    """pyigtl's own OpenIGTLinkClient, keeping every message it receives in order (``log``): pyigtl keeps only the
    newest message per device, and the live-link tests count and compare all of them."""

    def __init__(self, port: int):
        import pyigtl

        class _Client(pyigtl.OpenIGTLinkClient):
            def _receive_message_from_socket(inner, sock):
                received = pyigtl.OpenIGTLinkClient._receive_message_from_socket(inner, sock)
                if received:
                    with inner.lock_incoming_messages:
                        self.log.extend(inner.incoming_messages.values())
                        inner.incoming_messages.clear()
                return received

        self.log = []
        self._client = _Client(host="127.0.0.1", port=port)

    def messages(self, device: str) -> list:
        return [m for m in list(self.log) if m.device_name == device]

    def wait_for(self, condition, timeout_s: float = 30.0) -> bool:
        """Poll ``condition(self)`` (see ``poll``) until it holds or ``timeout_s`` has passed (a deadline, never a timed
        assertion)."""
        return poll(lambda: condition(self), timeout_s, interval_s=0.02)

    def stop(self) -> None:
        self._client.stop()


@pytest.fixture
def igtl_client():
    """``igtl_client(port)``: a started pyigtl client recording every message; stopped after the test."""
    clients = []

    def connect(port: int) -> RecordingIgtlClient:
        clients.append(RecordingIgtlClient(port))
        return clients[-1]

    yield connect
    for client in clients:
        client.stop()


VIDEO_FIXES = 10          # fixes per node of the recorded_video session


def start_video(session, fps, width, height, timeout_s: float = 60.0):
    """Start recording video and wait for its encoder (a second or two; until then pairs are not in the video)."""
    import time
    session.start_video(fps, width, height)
    deadline = time.monotonic() + timeout_s
    while not session.video_state().started:
        assert time.monotonic() < deadline and not session.video_state().problem, session.video_state().problem
        time.sleep(0.01)


@pytest.fixture(scope="session")
def recorded_video(tmp_path_factory):
    """A session recorded with video: the phantom tour at 480x270 (a quarter of the thesis cameras), level IMU, every
    node auto-stored after VIDEO_FIXES still fixes, labelled. Returns (path, scene, cameras)."""
    from snreg.camera import thesis_calibration
    from snreg.chain import ChainCalibration
    from snreg.demo.scene import PhantomScene, Schedule
    from snreg.probe import default_probe_model
    from snreg.session import Session
    from snreg.sources import CallableSource
    from snreg.workflow.acquisition import Acquisition, ImuReading
    folder = tmp_path_factory.mktemp("video")
    cameras, probe = thesis_calibration().scaled(0.25), default_probe_model()
    scene = PhantomScene(cameras, probe, Schedule(rest_frames=VIDEO_FIXES + 4, move_frames=3), seed=3)
    path = folder / "s.h5"
    with Session.create(path, case_id="video-1") as session:
        session.set_calibration(stereo=cameras, chain=ChainCalibration.manual())
        start_video(session, 30.0, *cameras.image_size)
        acquisition = Acquisition(cameras, probe, ChainCalibration.manual(), session, fixes_per_node=VIDEO_FIXES,
                                  video_fps=30.0)
        for frame in CallableSource(scene.render, 30.0, scene.schedule.cycle, start_ns=10**12):
            outcome = acquisition.process(frame, ImuReading(np.eye(3)))
            if outcome.auto_store_due:
                label = ("OBT R", "EXT L", "EXT R", "OBT L")[scene.resting_node(frame.index)]
                acquisition.store(session.next_node_id(), label, left_jpeg=frame.left, right_jpeg=frame.right)
        assert "video: recording" in outcome.video
    return path, scene, cameras
