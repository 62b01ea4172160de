"""The demo end to end in the app, offscreen (issue 6 "store nodes in the demo, register, export"): the four phantom
nodes auto-stored from the rendered feeds, the phantom SPECT segmented in the registration panel, registered on the
first Run from gravity with no angle typed (issue 30: the SPECT's patient position HFS, the table tilted 27 degrees
while the panel assumes the default 30, the IMU through the chain), paired as the phantom truth says, and exported."""

import numpy as np
import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QFileDialog

from snreg.demo.rig import DemoRig
from snreg.demo.scene import NODE_CENTRES_MM, Schedule
from snreg.nodes import read_nodes
from snreg.preop.gravity import PreopDown
from snreg.session import Session
from snreg_gui.app import MainWindow

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)

FIXES = 20


@pytest.mark.slow
def test_demo_store_register_export(qtbot, tmp_path, monkeypatch):
    rig = DemoRig(schedule=Schedule(rest_frames=FIXES + 25, move_frames=3), hold_rests=True)   # as snreg-gui --demo
    window = MainWindow(str(tmp_path / "demo.h5"), demo=True, rig=rig, fixes_per_node=FIXES)
    qtbot.addWidget(window)
    window.show()
    screen, panel = window.acquisition, window.registration
    screen.auto_store.setChecked(True)
    # held rests end on their stores, however slow the computer: the timeout is a deadline, not a measurement
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == len(NODE_CENTRES_MM), timeout=240_000)
    qtbot.waitUntil(lambda: panel.preop_box.nodes is not None and len(panel.preop_box.nodes) == 4, timeout=20_000)
    # labelled with the SPECT's report of stations, as snreg demo --headless labels them: they pair on station too
    assert panel.preop_box.status.text().endswith(", stations from demo-stations.csv")
    assert sorted(label.split()[0] for label in panel.preop_box.nodes.labels) == ["EXT", "EXT", "OBT", "OBT"]
    window.tabs.setCurrentWidget(panel)
    qtbot.waitUntil(lambda: panel.intraop_table.rowCount() == 4, timeout=5_000)    # the panel follows the stored nodes
    qtbot.waitUntil(lambda: window.session.preop_nodes() is not None, timeout=5_000)  # saved when loaded, before a Run
    assert window.session.preop_down() == PreopDown("HFS")         # with its down: supine, default tilt
    assert panel.alignment.angles_deg == (0.0, 0.0, 0.0)            # nothing pre-filled from the simulator's truth
    gravity = "start: gravity, table tilt 30 deg head down (default), heading searched"
    assert panel.start_box.status.text().startswith("Next run's start: gravity, table tilt 30 deg")
    qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    # an automatic run after the last store may still be under way: Run then runs again when it ends (and stores)
    qtbot.waitUntil(lambda: panel.message.text() == "Stored in the session as registration 0." and not panel.busy,
                    timeout=30_000)
    result = panel.last_result
    assert result.rms_mm <= 3.0 and np.all(result.pairing >= 0)
    assert gravity in panel.summary.text().splitlines()

    # truth: each stored node pairs with the segmented node nearest to its own source
    session = window.session
    records = session.intraop_records()
    tips = np.array([rig.scene.truth_tip(k) for k in range(4)])
    sources = rig.phantom_sources_lps()
    preop = panel.preop_box.nodes.xyz
    for k, node in enumerate(records):
        source = int(np.argmin(np.linalg.norm(tips - node.xyz_camera, axis=1)))
        assert result.pairing[k] == int(np.argmin(np.linalg.norm(preop - sources[source], axis=1)))

    target = tmp_path / "pairs.mrk.json"
    monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *a, **k: (str(target), ""))
    qtbot.mouseClick(panel.export_buttons["slicer"], Qt.MouseButton.LeftButton)
    def written():
        assert panel.message.text() == f"Written {target}.", panel.message.text()     # on a timeout: what it said

    qtbot.waitUntil(written, timeout=10_000)
    assert len(read_nodes(target)) == 4
    path = session.path
    window.shutdown()
    with Session.open(path) as reopened:
        assert len(reopened.registrations()) == 1 and len(reopened.preop_nodes()) == 4
