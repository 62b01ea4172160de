"""The stereo calibration wizard, driven offscreen on a rendered checkerboard feed with a known calibration."""

import threading
from pathlib import Path

import numpy as np
import pytest
from PySide6.QtCore import QPoint, Qt
from PySide6.QtWidgets import QWizard

import snreg.workflow.stereo_capture as feed_module
from snreg.calibration.checkerboard import THESIS_BOARD, Board, find_corners
from snreg.calibration.coverage import similar_view
from snreg.camera import load_calibration, thesis_calibration
from snreg.demo.board_render import random_board_poses, render_stereo_board, right_from_left
from snreg.demo.board_tour import BoardSchedule, BoardTour, board_feed
from snreg.sources import CallableSource, SourceError, SourceState
from snreg_gui.wizards.stereo.capture import STILL_FRAMES
from snreg_gui.wizards.stereo.wizard import StereoCalibrationWizard

TRUTH = thesis_calibration().scaled(0.5)          # the rendered cameras: 960 x 540
CLICKED_VIEWS = 10
LEFT = Qt.MouseButton.LeftButton


@pytest.fixture(scope="module")
def tour():
    """16 poses, two frames each, rendered once for the module; ``tour.source`` makes a feed."""
    tour = BoardTour(TRUTH, THESIS_BOARD, n_poses=16, schedule=BoardSchedule(dwell_frames=2, move_frames=0), seed=5)
    tour.prerender()
    return tour


@pytest.fixture(scope="module")
def still_tour():
    """Four poses, each held long enough to count as still (auto-capture)."""
    tour = BoardTour(TRUTH, THESIS_BOARD, n_poses=4, schedule=BoardSchedule(dwell_frames=STILL_FRAMES + 1, move_frames=0),
                     seed=8)
    tour.prerender()
    return tour


def blank_frames(index):
    grey = np.full((TRUTH.image_size[1], TRUTH.image_size[0], 3), 110, np.uint8)
    return grey, grey


@pytest.fixture
def open_wizard(qtbot):
    wizards = []

    def open_(make_source, board=THESIS_BOARD, **kwargs):
        wizard = StereoCalibrationWizard(make_source, board, **kwargs)
        qtbot.addWidget(wizard)
        with qtbot.waitExposed(wizard):
            wizard.show()
        wizards.append(wizard)
        return wizard

    yield open_
    for wizard in wizards:
        wizard.shutdown()


def click(qtbot, wizard, which):
    qtbot.mouseClick(wizard.button(which), LEFT)


def tick(qtbot, checkbox):
    """Click a check box on its box (its centre may lie past the end of its text)."""
    qtbot.mouseClick(checkbox, LEFT, pos=QPoint(8, checkbox.height() // 2))
    assert checkbox.isChecked()


def to_capture(qtbot, wizard):
    click(qtbot, wizard, QWizard.WizardButton.NextButton)
    assert wizard.currentPage() is wizard.capture_page


def capture_new_view(qtbot, page, tour=None, captured_poses=None):
    """Wait until both eyes see the board in a place not captured yet, then click Capture view.

    With a ``tour`` and ``captured_poses`` (a set, updated), wait for a pose of the tour not taken yet.
    """
    def ready():
        if not (page.capture_button.isEnabled() and not page.warning_label.text()):
            return False
        return tour is None or tour.pose_at(page.latest_view.index)[0] not in captured_poses

    n = len(page.views)
    qtbot.waitUntil(ready, timeout=15_000)
    if tour is not None:
        captured_poses.add(tour.pose_at(page.latest_view.index)[0])
    qtbot.mouseClick(page.capture_button, LEFT)
    assert len(page.views) == n + 1


# -- the rendered feed -----------------------------------------------------------------

def test_board_feed_dwells_moves_repeats_and_is_seeded():
    small = thesis_calibration().scaled(0.25)
    schedule = BoardSchedule(dwell_frames=3, move_frames=2)
    frames = [f for _, f in zip(range(16), board_feed(small, n_poses=3, schedule=schedule, seed=1))]
    same = lambda a, b: np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)  # noqa: E731
    assert same(frames[0], frames[2]) and not same(frames[2], frames[3])       # dwell, then move
    assert not same(frames[3], frames[4]) and not same(frames[4], frames[5])   # every moving frame is new
    assert same(frames[0], frames[15])                                          # a tour is 3 x 5 frames
    again = board_feed(small, n_poses=3, schedule=schedule, seed=1).read()
    other = board_feed(small, n_poses=3, schedule=schedule, seed=2).read()
    assert same(frames[0], again) and not same(frames[0], other)
    assert frames[0].left.shape == (small.image_size[1], small.image_size[0], 3)


def test_board_tour_truth_matches_the_rendered_corners():
    small = thesis_calibration().scaled(0.25)
    tour = BoardTour(small, THESIS_BOARD, n_poses=2, schedule=BoardSchedule(dwell_frames=2, move_frames=3), seed=4)
    for index in (0, 3):                                        # resting, and half way to the next pose
        left, right = tour.render(index)
        pose = tour.camera_from_board(index)
        for image, K, camera_from_board in ((left, small.K1, pose), (right, small.K2, right_from_left(small) @ pose)):
            points = (np.c_[THESIS_BOARD.object_points(), np.ones(THESIS_BOARD.n_corners)] @ camera_from_board.T)[:, :3]
            projected = points @ K.T
            found = find_corners(image, THESIS_BOARD)
            assert np.abs(found - projected[:, :2] / projected[:, 2:]).max() < 0.3
    centre = [45.0, 30.0, 0.0, 1.0]                               # the board's middle glides on a straight line
    centres = [(tour.camera_from_board(i) @ centre)[:3] for i in (1, 2, 3, 5)]    # u = 0, 1/4, 1/2, then arrived
    np.testing.assert_allclose(centres[1] - centres[0], (centres[3] - centres[0]) / 4, atol=1e-9)
    np.testing.assert_allclose(centres[2] - centres[0], (centres[3] - centres[0]) / 2, atol=1e-9)


# -- setup -----------------------------------------------------------------------------

def test_setup_defaults_from_the_board_and_a_bad_board_blocks_next(qtbot, open_wizard):
    wizard = open_wizard(lambda: BoardTour(board=Board(9, 6, 25.0)).source(), Board(9, 6, 25.0), target_views=20)
    page = wizard.setup_page
    assert (page.cols.value(), page.rows.value(), page.square_mm.value(), page.target_views.value()) == (9, 6, 25.0, 20)
    next_button = wizard.button(QWizard.WizardButton.NextButton)
    assert next_button.isEnabled()
    page.rows.setValue(9)
    assert not next_button.isEnabled() and "must differ" in page.problem.text()
    page.rows.setValue(6)
    assert next_button.isEnabled() and page.board() == Board(9, 6, 25.0)
    assert not wizard.has_running_workers()                  # the feed starts only on the capture page


def test_the_setup_numbers_stay_number_sized_in_the_wide_dialog(qtbot, open_wizard):
    """Issue 28: the board's number fields stretched about 730 px across the 1200 px dialog."""
    wizard = open_wizard(lambda: BoardTour(board=Board(9, 6, 25.0)).source(), Board(9, 6, 25.0))
    wizard.resize(1200, 800)
    with qtbot.waitExposed(wizard):
        wizard.show()
    page = wizard.setup_page
    for field in (page.cols, page.rows, page.square_mm, page.target_views):
        qtbot.waitUntil(lambda f=field: f.width() > 0, timeout=2_000)
        assert field.width() <= max(field.sizeHint().width(), 200)
        assert field.width() < 0.25 * wizard.width()


# -- capture, calibrate, drop, save ------------------------------------------------------

@pytest.mark.slow
def test_capture_calibrate_drop_and_save(qtbot, open_wizard, tour, tmp_path):
    wizard = open_wizard(tour.source, target_views=12)
    page = wizard.capture_page
    to_capture(qtbot, wizard)
    assert page.coverage_label.text() == "coverage: no views yet"
    totals, fractions, poses = [], [], set()
    for _ in range(CLICKED_VIEWS):
        capture_new_view(qtbot, page, tour, poses)
        totals.append([c.counts.sum() for c in page.coverage])
        fractions.append([c.fraction_covered for c in page.coverage])
        np.testing.assert_array_equal(page.left_view.heat_counts, page.coverage[0].counts)   # the map shows them
    corners = THESIS_BOARD.n_corners
    assert totals == [[corners * n, corners * n] for n in range(1, CLICKED_VIEWS + 1)]
    assert np.all(np.diff(fractions, axis=0) >= 0) and fractions[-1][0] > 2 * fractions[0][0]
    assert page.count_label.text() == f"{CLICKED_VIEWS} of 12 views"

    click(qtbot, wizard, QWizard.WizardButton.NextButton)
    calibrate = wizard.calibrate_page
    assert wizard.currentPage() is calibrate and calibrate.progress.isVisible()
    qtbot.waitUntil(calibrate.isComplete, timeout=20_000)
    result = calibrate.result
    assert result.n_views == CLICKED_VIEWS and not result.skipped
    focal_error = max(abs(result.calibration.K1[0, 0] / TRUTH.K1[0, 0] - 1), abs(result.calibration.K2[1, 1] / TRUTH.K2[1, 1] - 1))
    baseline_error = abs(result.calibration.baseline_mm / TRUTH.baseline_mm - 1)
    print(f"{CLICKED_VIEWS} views: RMS {result.rms_px:.3f} px, focal error {focal_error:.3%}, "
          f"baseline {result.calibration.baseline_mm:.4f} mm (truth {TRUTH.baseline_mm:.4f}, error {baseline_error:.3%}), "
          f"reconstruction {result.reconstruction_error_mm:.4f} mm")
    assert focal_error < 0.01 and baseline_error < 0.01
    assert f"baseline {result.calibration.baseline_mm:.3f} mm" in calibrate.summary.text()
    assert calibrate.table.rowCount() == CLICKED_VIEWS and not calibrate.progress.isVisible()

    assert not calibrate.recalibrate_button.isEnabled()                   # nothing ticked yet
    calibrate.table.item(2, 0).setCheckState(Qt.CheckState.Checked)
    assert calibrate.recalibrate_button.isEnabled()
    qtbot.mouseClick(calibrate.recalibrate_button, LEFT)
    qtbot.waitUntil(lambda: calibrate.isComplete() and calibrate.result.n_views == CLICKED_VIEWS - 1, timeout=20_000)
    assert 2 not in calibrate.result.view_ids and calibrate.table.rowCount() == CLICKED_VIEWS - 1

    click(qtbot, wizard, QWizard.WizardButton.NextButton)
    save = wizard.save_page
    proposed = Path(save.path_edit.text())                       # never a bare relative calibration.yaml
    assert proposed.is_absolute() and proposed.name.startswith("calibration_stereo_") and proposed.suffix == ".yaml"
    save.path_edit.setText(str(tmp_path / "missing" / "calib.yaml"))
    with qtbot.assertNotEmitted(wizard.calibrated):                     # nothing applied that was not saved
        click(qtbot, wizard, QWizard.WizardButton.FinishButton)
    assert wizard.isVisible() and "does not exist" in save.status.text()
    path = tmp_path / "calib.yaml"
    save.path_edit.setText(str(path))
    with qtbot.waitSignal(wizard.calibrated, timeout=5_000) as emitted:
        click(qtbot, wizard, QWizard.WizardButton.FinishButton)
    loaded, calibration = load_calibration(path), emitted.args[0]
    assert loaded.n_views == CLICKED_VIEWS - 1 and calibration.n_views == CLICKED_VIEWS - 1
    np.testing.assert_allclose(loaded.K1, calibration.K1)
    np.testing.assert_allclose(loaded.T, calibration.T)
    assert not wizard.isVisible() and not wizard.has_running_workers() and wizard.saved_path == path


# -- board not visible, feed problems, threads -------------------------------------------

def test_capture_is_disabled_with_a_reason_when_an_eye_misses_the_board(qtbot, open_wizard, monkeypatch):
    searched_on_gui_thread = []
    original = feed_module.find_corners

    def spy(image, board):
        searched_on_gui_thread.append(threading.current_thread() is threading.main_thread())
        return original(image, board)

    monkeypatch.setattr(feed_module, "find_corners", spy)
    wizard = open_wizard(lambda: CallableSource(blank_frames, 30.0))
    page = wizard.capture_page
    to_capture(qtbot, wizard)
    qtbot.waitUntil(lambda: page.latest_view is not None, timeout=10_000)
    assert not page.capture_button.isEnabled()
    assert "board not found in left" in page.capture_reason.text() and "board not found in left" in page.capture_button.toolTip()
    assert page.left_view.message == "board not found in left"
    assert searched_on_gui_thread and not any(searched_on_gui_thread)

    pose = random_board_poses(TRUTH, THESIS_BOARD, 1, seed=3)[0]
    left, _ = render_stereo_board(TRUTH, THESIS_BOARD, pose, bgr=True)
    right_blind = open_wizard(lambda: CallableSource(lambda i: (left, blank_frames(i)[1]), 30.0))
    page = right_blind.capture_page
    to_capture(qtbot, right_blind)
    qtbot.waitUntil(lambda: page.latest_view is not None, timeout=10_000)
    assert not page.capture_button.isEnabled() and page.detection_label.text() == "board not found in right"
    assert page.right_view.message == "board not found in right"


def test_the_source_ending_or_failing_is_said_in_its_sentence_and_next_reopens_it(qtbot, open_wizard):
    made = []

    def make():
        made.append(CallableSource(blank_frames, 30.0, n_frames=3))
        return made[-1]

    wizard = open_wizard(make)
    status = wizard.capture_page.feed_status
    to_capture(qtbot, wizard)
    qtbot.waitUntil(lambda: bool(made) and made[0].state is SourceState.ENDED and bool(status.text()), timeout=10_000)
    assert status.text() == made[0].problem == "Synthetic source rendered all 3 frames."
    assert not wizard.capture_page.capture_button.isEnabled()
    click(qtbot, wizard, QWizard.WizardButton.BackButton)
    to_capture(qtbot, wizard)
    qtbot.waitUntil(lambda: len(made) == 2 and made[1].state is SourceState.ENDED, timeout=10_000)

    def unplugged():
        raise SourceError("Cannot open camera 0: check that it is connected.")

    failing = open_wizard(unplugged)
    to_capture(qtbot, failing)
    qtbot.waitUntil(lambda: bool(failing.capture_page.feed_status.text()), timeout=10_000)
    assert failing.capture_page.feed_status.text() == "Cannot open camera 0: check that it is connected."


@pytest.mark.slow
def test_auto_capture_takes_only_still_new_places(qtbot, open_wizard, still_tour):
    wizard = open_wizard(still_tour.source, target_views=3)
    page = wizard.capture_page
    to_capture(qtbot, wizard)
    tick(qtbot, page.auto_capture)
    qtbot.waitUntil(lambda: len(page.views) == 3, timeout=20_000)
    size = TRUTH.image_size
    for k, view in enumerate(page.views):
        assert similar_view(view.stacked_corners, [v.stacked_corners for v in page.views[:k]], size) is None
    last = page.latest_view.index
    # auto-capture fires STILL_FRAMES into a rest: one period later the fourth pose was as still, but the target is met
    qtbot.waitUntil(lambda: page.latest_view.index > last + still_tour.schedule.period + 1, timeout=10_000)
    assert len(page.views) == 3


def test_a_repeated_view_is_warned_about_and_not_auto_captured(qtbot, open_wizard):
    never_moving = BoardTour(TRUTH, THESIS_BOARD, n_poses=1, seed=8)
    wizard = open_wizard(never_moving.source)
    page = wizard.capture_page
    to_capture(qtbot, wizard)
    capture_new_view(qtbot, page)
    tick(qtbot, page.auto_capture)
    first = page.latest_view.index
    qtbot.waitUntil(lambda: page.latest_view.index > first + 2 * STILL_FRAMES, timeout=10_000)
    assert len(page.views) == 1 and page.warning_label.text().startswith("Too similar to view 1")
    qtbot.mouseClick(page.capture_button, LEFT)                # the operator may insist
    assert len(page.views) == 2 and "much like view 1" in page.warning_label.text()
    assert wizard.button(QWizard.WizardButton.NextButton).isEnabled() is False      # 3 views needed

    click(qtbot, wizard, QWizard.WizardButton.BackButton)      # another board: the views are of no use
    wizard.setup_page.cols.setValue(9)
    to_capture(qtbot, wizard)
    assert page.views == [] and "2 views of the 10x7 board were discarded" in page.count_label.text()


def test_closing_mid_capture_or_mid_calibration_leaves_no_thread(qtbot, open_wizard, tour):
    sources = []

    def make():
        sources.append(tour.source())
        return sources[-1]

    wizard = open_wizard(make)
    page = wizard.capture_page
    to_capture(qtbot, wizard)
    qtbot.waitUntil(lambda: page.latest_view is not None, timeout=10_000)
    assert wizard.has_running_workers()
    wizard.close()
    assert not wizard.has_running_workers() and not wizard.isVisible()
    assert sources[0].state is SourceState.ENDED and "closed" in sources[0].problem

    emitted = []
    calibrating = open_wizard(make)
    calibrating.calibrated.connect(emitted.append)
    to_capture(qtbot, calibrating)
    for _ in range(3):
        capture_new_view(qtbot, calibrating.capture_page)
    click(qtbot, calibrating, QWizard.WizardButton.NextButton)
    assert calibrating.calibrate_page.progress.isVisible()      # calibrating now
    click(qtbot, calibrating, QWizard.WizardButton.CancelButton)
    assert not calibrating.has_running_workers() and not calibrating.isVisible()
    assert sources[1].state is SourceState.ENDED and emitted == []
