"""The offline review screen (snreg_gui.review.screen), driven for real on a session recorded in the test."""

import h5py
import numpy as np
import pytest
from PySide6.QtCore import Qt
from test_session_timeline import (CAMERA_LAG_S, DURATION_S, FRAME_RATE_HZ, LOST_FRAMES, PREOP_IDS, STEREO_RMS_PX,
                                   YAW_TURN_DEG, damaged_copy, record_session)

from snreg.session.schema import FORMAT_VERSION
from snreg_gui.review.screen import ReviewScreen
from snreg_gui.review.timelines import label_anchor, label_rows

LOAD_TIMEOUT_MS = 20_000


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("review_gui") / "s.h5"
    return path, record_session(path)


@pytest.fixture
def screen(qtbot):
    widget = ReviewScreen()
    qtbot.addWidget(widget)
    widget.resize(1400, 900)
    widget.show()
    return widget


def _load(qtbot, screen, path):
    with qtbot.waitSignal(screen.loaded, timeout=LOAD_TIMEOUT_MS) as blocker:
        screen.load(path)
    assert blocker.args == [str(path)]


def _click_row(qtbot, table, row):
    rect = table.visualItemRect(table.item(row, 0))
    qtbot.mouseClick(table.viewport(), Qt.MouseButton.LeftButton, pos=rect.center())


def test_header_nodes_and_registrations(qtbot, screen, recorded):
    path, truth = recorded
    _load(qtbot, screen, path)
    header = screen.header.text()
    assert str(path) in header and "case review-01" in header and f"format version {FORMAT_VERSION}" in header
    assert f"stereo RMS {STEREO_RMS_PX:.2f} px" in header and "IMU-trocar 460.0 mm, trocar-camera 158.0 mm" in header
    assert "DAMAGED" not in header and "1 gap, longest 0.53 s" in header
    table = screen.node_table
    assert table.rowCount() == 3
    assert [table.item(r, 0).text() for r in range(3)] == truth.node_ids
    assert [float(table.item(r, 2).text()) for r in range(3)] == pytest.approx(truth.node_times_s)
    for row in range(3):             # the rest of each record in its row's tooltip, on every cell (six columns fit)
        tips = {table.item(row, c).toolTip() for c in range(table.columnCount())}
        assert len(tips) == 1 and "camera x, y, z: " in tips.pop()
    assert table.horizontalScrollBar().maximum() == 0
    regs = screen.registrations
    assert regs.list.rowCount() == 1
    assert (regs.list.item(0, 1).text(), regs.list.item(0, 2).text()) == ("global", f"{truth.rms_mm:.2f}")
    assert regs.list.item(0, 3).text() == "3 of 3"
    assert regs.pairs.rowCount() == 0                       # none chosen yet: no pairs (issue 35)
    _click_row(qtbot, regs.list, 0)
    assert [regs.pairs.item(r, 0).text() for r in range(3)] == [f"{i} -> {p}" for i, p in zip(truth.node_ids,
                                                                                            PREOP_IDS)]
    with h5py.File(path, "r+"):            # the screen holds nothing open
        pass


def test_selecting_a_node_shows_its_snapshots_and_moves_the_cursor(qtbot, screen, recorded):
    path, truth = recorded
    _load(qtbot, screen, path)
    assert all(not cursor.isVisible() for cursor in screen.timelines.cursors)
    for row in (1, 2):
        _click_row(qtbot, screen.node_table, row)
        left, right = truth.snapshot_shapes[row]
        assert screen.snapshots.left_view.frame.shape == left
        assert screen.snapshots.right_view.frame.shape == right
        assert screen.snapshots.left_view.frame.reshape(-1, 3).mean(0) == pytest.approx([255, 0, 0], abs=3)
        for cursor in screen.timelines.cursors:
            assert cursor.isVisible() and cursor.value() == pytest.approx(truth.node_times_s[row])


def test_timelines_show_fused_yaw_node_markers_and_frames(qtbot, screen, recorded):
    path, truth = recorded
    _load(qtbot, screen, path)
    timelines = screen.timelines
    t, yaw = timelines.imu_curves[0].getOriginalDataset()
    assert len(t) == len(yaw) == timelines.imu_shown == int(DURATION_S * 208)
    assert yaw[-1] == pytest.approx(YAW_TURN_DEG, abs=0.5)
    assert np.abs(yaw[t < 2.9]).max() < 0.3
    assert sorted(timelines.node_markers) == truth.node_ids
    for node_id, t_node in zip(truth.node_ids, truth.node_times_s):
        lines = timelines.node_markers[node_id]
        assert len(lines) == len(timelines.plots)
        assert [line.value() for line in lines] == pytest.approx([t_node] * len(lines))
    assert timelines.node_markers["SN2"][0].label.textItem.toPlainText() == "SN2"
    gap_x, _ = timelines.gap_curve.getOriginalDataset()
    edges = np.array([LOST_FRAMES[0] - 1, LOST_FRAMES[-1] + 1]) / FRAME_RATE_HZ + CAMERA_LAG_S
    assert gap_x == pytest.approx(edges)             # one red bar from the last frame before the gap to the next
    tip_t, tip_y = timelines.tip_curves[1].getOriginalDataset()
    assert tip_y == pytest.approx(2 * (tip_t - CAMERA_LAG_S), abs=1e-4)


def test_a_recording_gap_is_drawn_as_a_gap(qtbot, screen, tmp_path):
    """Acquisition paused 60 s (a calibration): the tip and angle curves break there instead of bridging it, and only
    there, though the serial reader stamps the IMU's samples on the host in bursts (4 at a time here)."""
    from snreg.session import Session
    t = np.concatenate([np.arange(60) / 30, 62.0 + np.arange(60) / 30])
    t_imu = np.concatenate([np.arange(416) / 208, 62.0 + np.arange(416) / 208])
    t_imu_host = np.repeat(t_imu[3::4], 4)                    # each burst stamped when its last sample came
    host, host_imu = (np.round(1e12 + v * 1e9).astype(np.int64) for v in (t, t_imu_host))
    with Session.create(tmp_path / "gap.h5", case_id="gap-1", stream_flush_s=0) as s:
        s.append_imu(host_imu, (t_imu * 1e9).astype(np.int64), np.tile([0.0, 0.0, 1.0], (len(t_imu), 1)),
                     np.zeros((len(t_imu), 3)))
        s.append_probe(host, host, np.column_stack([t, t, t]), np.zeros((len(t), 3)), np.tile([0, 0, 1.0], (len(t), 1)),
                       np.ones(len(t)))
        s.append_frames(host, host, np.arange(len(t)))
    _load(qtbot, screen, tmp_path / "gap.h5")
    qtbot.waitUntil(lambda: screen.timelines.imu_shown == len(t_imu), timeout=LOAD_TIMEOUT_MS)
    tip_t, tip_y = screen.timelines.tip_curves[0].getOriginalDataset()
    assert len(tip_t) == len(t) + 1 and np.isnan(tip_y[60]) and tip_t[61] == pytest.approx(62.0)
    imu_t, yaw = screen.timelines.imu_curves[0].getOriginalDataset()
    assert len(imu_t) == len(t_imu) + 1 and np.isnan(imu_t[416]) and np.isfinite(yaw[417:]).all()
    assert np.isfinite(imu_t[:416]).all() and np.isfinite(imu_t[417:]).all()      # one line on each side of the gap


def test_a_damaged_file_says_so_and_shows_its_journal(qtbot, screen, recorded, tmp_path):
    path, truth = recorded
    damaged = damaged_copy(path, tmp_path)
    _load(qtbot, screen, damaged)
    assert "DAMAGED" in screen.header.text() and "streams: IMU 0 samples" in screen.header.text()
    assert "the HDF5 file cannot be read" in screen.header.text()      # what is damaged, in words
    assert screen.node_table.rowCount() == len(truth.node_ids) and screen.timelines.imu_shown == 0
    assert screen.minimumSizeHint().width() <= 900                     # the long damage line wraps (1024 x 700)


@pytest.mark.parametrize("kind", ["text renamed .h5", "foreign HDF5", "missing"])
def test_unreadable_file_gives_one_sentence(qtbot, screen, recorded, tmp_path, kind):
    good, _ = recorded
    _load(qtbot, screen, good)
    path = tmp_path / "notes.h5"
    if kind == "text renamed .h5":
        path.write_text("patient list, not a session\n")
    elif kind == "foreign HDF5":
        with h5py.File(path, "w") as f:
            f["volume"] = np.zeros((4, 4))
    with qtbot.waitSignal(screen.failed, timeout=LOAD_TIMEOUT_MS) as blocker:
        screen.load(path)
    (sentence,) = blocker.args
    assert str(path) in sentence and "\n" not in sentence and "Traceback" not in sentence
    assert screen.status.text() == sentence
    assert screen.node_table.rowCount() == 0 and screen.registrations.list.rowCount() == 0
    assert screen.timelines.node_markers == {} and screen.timelines.imu_shown == 0


def test_a_new_load_supersedes_a_running_one(qtbot, screen, recorded, tmp_path):
    path, truth = recorded
    failures = []
    screen.failed.connect(failures.append)
    screen.load(tmp_path / "missing.h5")
    _load(qtbot, screen, path)
    assert failures == [] and screen.node_table.rowCount() == len(truth.node_ids)


def test_closing_while_loading_waits_for_the_worker_and_a_later_load_works(qtbot, screen, recorded):
    path, truth = recorded
    emitted = []
    screen.loaded.connect(emitted.append)
    screen.load(path)
    screen.close()                         # returns once the worker's thread has ended
    screen.show()
    _load(qtbot, screen, path)
    assert emitted == [str(path)] and screen.node_table.rowCount() == len(truth.node_ids)


def test_mark_and_unmark_final_in_a_saved_session(qtbot, screen, recorded, tmp_path):
    import shutil

    from snreg.session import Session
    from snreg.session.journal import journal_path

    source, _ = recorded
    path = tmp_path / "copy.h5"
    shutil.copy(source, path)
    if journal_path(source).exists():
        shutil.copy(journal_path(source), journal_path(path))
    _load(qtbot, screen, path)
    regs = screen.registrations
    assert regs.list.item(0, 4).text() == "" and not regs.unmark_button.isEnabled()
    _click_row(qtbot, regs.list, 0)
    with qtbot.waitSignal(screen.final_changed) as blocker:
        qtbot.mouseClick(regs.mark_button, Qt.MouseButton.LeftButton)
    assert blocker.args == [0] and regs.list.item(0, 4).text() == "FINAL" and regs.unmark_button.isEnabled()
    with Session.open(path) as session:
        assert session.final_registration() == 0
    qtbot.mouseClick(regs.unmark_button, Qt.MouseButton.LeftButton)
    assert regs.list.item(0, 4).text() == ""
    with Session.open(path) as session:
        assert session.final_registration() is None


def test_axes_never_scale_degrees_with_an_si_prefix(qtbot, screen, recorded):
    path, _ = recorded
    _load(qtbot, screen, path)
    for plot in screen.timelines.plots:
        plot.setYRange(-0.004, 0.004)                                # would read "(x0.001)" with the prefix on
        for side in ("left", "bottom"):
            axis = plot.getAxis(side)
            assert not axis.autoSIPrefix and "(x" not in axis.labelString()
    assert screen.timelines.angles.getAxis("left").labelString().startswith("<span")
    assert "IMU (deg)" in screen.timelines.angles.getAxis("left").labelString()


def test_curve_colours_are_named_above_the_plots_where_node_labels_cannot_cover_them(screen):
    timelines = screen.timelines
    assert all(plot.legend is None for plot in timelines.plots)          # an in-plot legend sat under the labels
    key = timelines.key.text
    assert all(word in key for word in ("yaw", "pitch", "roll", "tip"))
    assert timelines.getItem(0, 0) is timelines.key and timelines.getItem(1, 0) is timelines.angles


def test_node_labels_close_in_time_go_on_different_rows():
    assert label_rows([0.0, 0.1, 0.2, 5.0, 5.05], 1.0) == [0, 1, 2, 0, 1]
    assert label_rows([5.0, 0.0, 0.1], 1.0) == [0, 0, 1]                  # in time order, whatever the input order
    assert label_rows([0.0, 2.0, 4.0], 1.0) == [0, 0, 0]                  # far apart: one row
    assert label_rows(np.arange(8) * 0.01, 1.0) == [0, 1, 2, 3, 4, 5, None, None]  # no row free: not shown


def test_timeline_labels_as_wide_as_their_text_take_rows_apart():
    assert label_rows([0.0, 3.0, 6.0], 0.0, [8.0, 1.0, 1.0]) == [0, 1, 0]   # the wide one covers 3 s, not 6 s
    assert label_rows([0.0, 3.0, 6.0], 0.0) == [0, 0, 0]                    # points: one row
    assert label_rows([0.0, 1.0, 2.0, 9.0], 0.0, [30.0, 2.0, 1.0, 1.0], max_rows=2) == [0, 1, None, 1]


def test_refresh_reads_a_session_still_being_recorded_again(qtbot, screen, tmp_path):
    from snreg.session import Session
    assert not screen.refresh_button.isEnabled()
    with Session.create(tmp_path / "live.h5", case_id="live-1") as session:
        session.add_intraop_node("SN1", "", [1.0, 2.0, 3.0])
        _load(qtbot, screen, session.path)
        assert screen.node_table.rowCount() == 1 and "Refresh reads it again" in screen.status.text()
        session.add_intraop_node("SN2", "", [4.0, 5.0, 6.0])            # stored after the screen read the file
        with qtbot.waitSignal(screen.loaded, timeout=LOAD_TIMEOUT_MS):
            qtbot.mouseClick(screen.refresh_button, Qt.MouseButton.LeftButton)
        assert screen.node_table.rowCount() == 2 and screen.path == str(session.path)


def test_a_label_at_the_plots_end_is_shifted_along_its_line_to_lie_inside():
    assert label_anchor(5.0, 2.0, 0.0, 10.0) == 0.5                       # room: centred on its line
    assert label_anchor(0.2, 2.0, 0.0, 10.0) == pytest.approx(0.1)        # at the left end: its left edge at 0
    assert label_anchor(9.9, 2.0, 0.0, 10.0) == pytest.approx(0.95)       # at the right end: its right edge at 10
    assert label_anchor(5.0, 20.0, 0.0, 10.0) == pytest.approx(0.25)      # wider than the plot: from its left end
