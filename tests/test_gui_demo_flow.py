"""The demo end to end in the app, offscreen (issue 6 "store nodes in the demo, register, export"): the four phantom
nodes auto-stored from the rendered feeds, the phantom SPECT segmented in the registration panel, the nominal
set-up alignment, registered on the first Run (the alignment starts from the centroids: issue 28), paired as the
phantom truth says, and exported."""

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QFileDialog

from snreg.demo.rig import DemoRig
from snreg.demo.scene import NODE_CENTRES_MM, Schedule
from snreg.nodes import read_nodes
from snreg.session import Session
from snreg_gui.app import MainWindow

FIXES = 20


def test_demo_store_register_export(qtbot, tmp_path, monkeypatch):
    rig = DemoRig(schedule=Schedule(rest_frames=FIXES + 25, move_frames=3))
    window = MainWindow(str(tmp_path / "demo.h5"), demo=True, rig=rig, fixes_per_node=FIXES)
    qtbot.addWidget(window)
    window.show()
    screen, panel = window.acquisition, window.registration
    screen.auto_store.setChecked(True)
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == len(NODE_CENTRES_MM), timeout=60_000)
    qtbot.waitUntil(lambda: panel.preop_box.nodes is not None and len(panel.preop_box.nodes) == 4, timeout=20_000)
    window.tabs.setCurrentWidget(panel)
    qtbot.waitUntil(lambda: panel.intraop_table.rowCount() == 4, timeout=5_000)    # the panel follows the stored nodes
    qtbot.waitUntil(lambda: window.session.preop_nodes() is not None, timeout=5_000)  # saved when loaded, before a Run
    with qtbot.waitSignal(panel.registered, timeout=30_000) as registered:
        qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
    result = registered.args[0]
    assert result.rms_mm <= 3.0 and np.all(result.pairing >= 0)

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
