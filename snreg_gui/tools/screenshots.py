"""Screenshots of every tab and every wizard page of the demo, at 1024x700 and 1366x768, for a person to look at.

    xvfb-run -a -s "-screen 0 1920x1080x24" .venv/bin/python -m snreg_gui.screenshots -o screenshots/
    QT_QPA_PLATFORM=offscreen .venv/bin/python -m snreg_gui.screenshots -o screenshots/ --only trocar
    QT_QPA_PLATFORM=offscreen .venv/bin/python -m snreg_gui.screenshots --docs -o docs/images/   # the guide's set
    QT_QPA_PLATFORM=offscreen .venv/bin/python -m snreg_gui.screenshots --docs --only navigation -o docs/images/

``--camera`` picks the demo (default surgery: the camera slides and turns between nodes, its insertion tracked; still:
the thesis' phantom). ``--docs`` takes the set the technician's guide shows (issue 35: every tab of the surgery demo
with nothing cut, at both sizes; each wizard page at the smallest, where a cut would show first; issue 36: the
acquisition feed with the hot spot not found yet on screen and off screen, at 1366x768), saved with a palette of 256
colours so the set stays small in the repository.

Why: offscreen tests prove behaviour, not that a screen reads well. This drives the demo as an operator would
(auto-store the four phantom nodes, pausing after three while the registration that follows each store leaves the
fourth hot spot unfound, to shoot the feed when that hot spot lies in the left image and when it lies outside it
with its edge arrow, as the camera's tour takes it; register against the phantom SPECT, go through both calibration
wizards page by page on their rendered scenes and finish them, refuse a store with the IMU unplugged, ask on close,
review the session) and saves each screen as ``<name>-<W>x<H>.png``. Under X (Xvfb) a shot is what the X
server shows; offscreen, the widget's own rendering. A shot is taken only once every camera feed on it shows a
frame, and the run fails (exit status 1) when any shot is blank: the whole image, or a feed's area, one flat
colour (:func:`~snreg_gui.tools.shooter.blank_reason`), as the trocar wizard's shot once was, taken before its
first frame.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QApplication, QMessageBox, QWizard

from snreg_gui.tools.layout_check import SCREEN_SIZES
from snreg_gui.tools.shooter import DOCS_NAVIGATION, DOCS_TABS, FEED_TIMEOUT_S, Shooter, spin, wait_until

SIZES = SCREEN_SIZES[:2]           # 1024x700 and 1366x768: where a cut shows first
STORE_TIMEOUT_S = 900.0           # the demo's four nodes auto-stored, on a loaded machine
NAVIGATION_NODES = 3              # stored before the navigation shots: the registration leaves the fourth unfound
NAVIGATION_WAIT_S = 300.0         # for a navigation shot's moment, without a camera tour to time it by
SURGERY_FIXES = 20                # fixes per node in the surgery demo's shots
SURGERY_SCALE = 0.25              # its cameras' resolution, of the thesis' 1920x1080
# the shots, by the part of the run that takes them (--only picks parts of these names)
PHASES = {"navigation": DOCS_NAVIGATION,
          "tabs": DOCS_TABS,
          "stereo": ("stereo-1-setup", "stereo-2-capture", "paused-for-calibration", "stereo-3-calibrate",
                     "stereo-4-save", "stereo-5-applied"),
          "trocar": ("trocar-1-method", "trocar-2-pivot", "trocar-2-tissue", "trocar-3-arc", "trocar-4-manual",
                     "trocar-5-summary", "trocar-6-applied"),
          "refusal": ("refused-store", "close-question"),
          "replay": ("replay-acquisition",)}


def hot_spot_marks(window) -> tuple:
    """The marks the acquisition's left feed draws now of the hot spots not found yet (() without any)."""
    layer = window.acquisition.left_feed.hot_spots
    return () if layer is None else layer.marks


def on_screen(window) -> bool:
    """A hot spot not found yet is drawn inside the left image (its 90 % ellipse)."""
    return any(mark.centre is not None for mark in hot_spot_marks(window))


def off_screen(window) -> bool:
    """A hot spot not found yet lies outside the left image: drawn as an arrow at its edge."""
    return any(mark.arrow_at is not None for mark in hot_spot_marks(window))


def _navigation(shots: Shooter, window) -> None:
    """Three nodes auto-stored, then auto-store off; once a registration of them leaves a hot spot unfound, the
    acquisition tab when the left feed draws it inside the image and when it draws it as an edge arrow (the surgery
    camera's tour decides which, so each shot waits for its own)."""
    screen, panel = window.acquisition, window.registration
    wait_until(lambda: screen.nodes.rowCount() >= NAVIGATION_NODES, STORE_TIMEOUT_S,
               f"{NAVIGATION_NODES} nodes to be stored")
    screen.auto_store.setChecked(False)
    if screen.nodes.rowCount() != NAVIGATION_NODES:
        raise SystemExit(f"screenshots: {screen.nodes.rowCount()} nodes were stored before auto-store was switched "
                         f"off; the navigation shots need {NAVIGATION_NODES}")
    wait_until(lambda: panel.preop_box.nodes is not None, 60, "the phantom SPECT")
    wait_until(lambda: not panel.busy, 120, "the registration after the third store")
    if not panel.navigation.targets or panel.navigation.stale:   # the SPECT came after the stores: register now
        panel.run_button.click()
    wait_until(lambda: bool(panel.navigation.targets) and not panel.navigation.stale and not panel.busy, 120,
               "a registration that leaves a hot spot unfound")
    tour_s = _tour_seconds(window.rig)           # a whole tour of the camera: what it never brings, it never will
    shots.shoot("navigation-on-screen", window, when=lambda: on_screen(window),
                what="hot spot not found yet inside the left image", give_up_s=tour_s)
    shots.shoot("navigation-off-screen", window, when=lambda: off_screen(window),
                what="hot spot not found yet outside the left image (an edge arrow)", give_up_s=tour_s)


def _tour_seconds(rig) -> float:
    """Wall-clock seconds of one whole tour of the demo's scene and a half, a minute more (its feed runs in real
    time); NAVIGATION_WAIT_S when the scene has no tour."""
    scene = getattr(rig, "scene", None)
    cycle = getattr(scene, "cycle", None)
    return NAVIGATION_WAIT_S if not cycle else 1.5 * cycle / rig.fps + 60.0


def _store_and_register(shots: Shooter, window) -> None:
    from snreg.demo.scene import NODE_CENTRES_MM
    screen, panel = window.acquisition, window.registration
    screen.auto_store.setChecked(True)
    if shots.wanted(*PHASES["navigation"]):
        _navigation(shots, window)
        if not shots.wanted(*PHASES["tabs"], *PHASES["refusal"], *PHASES["replay"]):
            return
        screen.auto_store.setChecked(True)
    wait_until(lambda: screen.nodes.rowCount() == len(NODE_CENTRES_MM), STORE_TIMEOUT_S, "the four nodes to be stored")
    screen.auto_store.setChecked(False)
    shots.shoot("tab-1-acquisition", window)
    window.tabs.setCurrentWidget(panel)
    wait_until(lambda: panel.preop_box.nodes is not None, 60, "the phantom SPECT")
    panel.auto_rerun.setChecked(False)
    panel.run_button.click()
    wait_until(lambda: panel.last_result is not None and not panel.busy, 120, "the registration")
    shots.shoot("tab-2-registration", window)
    window.tabs.setCurrentWidget(window._acquisition_tab)


def _stereo_wizard(shots: Shooter, window) -> None:
    from snreg.calibration.stereo import MIN_VIEWS
    window.wizards.stereo()
    wizard = window.wizards.active
    shots.shoot("stereo-1-setup", wizard)
    wizard.next()
    capture = wizard.capture_page
    capture.auto_capture.setChecked(True)
    wait_until(lambda: len(capture.views) >= MIN_VIEWS + 1, 400, "the stereo views to be captured")
    capture.auto_capture.setChecked(False)
    shots.shoot("stereo-2-capture", wizard)
    wizard.resize(700, 560)
    wizard.move(0, 130)                               # beside the acquisition side panel, which says it is paused
    shots.shoot("paused-for-calibration", window, box=wizard, centre_box=False)
    wizard.next()
    wait_until(lambda: wizard.calibrate_page.isComplete(), 300, "the stereo calibration")
    shots.shoot("stereo-3-calibrate", wizard)
    wizard.next()
    shots.shoot("stereo-4-save", wizard)
    wizard.button(QWizard.WizardButton.FinishButton).click()
    wait_until(lambda: window.wizards.active is None, 60, "the stereo wizard to finish")
    _shoot_calibration_box(shots, window, "stereo-5-applied")


def _shoot_calibration_box(shots: Shooter, window, name: str) -> None:
    """The box that says where the calibration was saved and that it is applied (or offers to re-express)."""
    wait_until(lambda: window.calibration_notice is not None or window.calibration_prompt is not None, 30,
               f"the box after {name}")
    box = window.calibration_prompt or window.calibration_notice
    shots.shoot(name, window, box=box)
    keep = [b for b in box.buttons() if box.buttonRole(b) == QMessageBox.ButtonRole.RejectRole]
    (keep or box.buttons())[0].click()
    spin(0.5)


def _trocar_wizard(shots: Shooter, window) -> None:
    window.wizards.trocar()
    wizard = window.wizards.active
    shots.shoot("trocar-1-method", wizard)
    if not shots.wanted(*PHASES["trocar"][1:]):
        return wizard.reject()
    wizard.next()                                    # pivot (recommended)
    page = wizard.pivot_page
    wait_until(lambda: len(page.samples) >= 3, FEED_TIMEOUT_S, "the pivot page's first samples")
    shots.shoot("trocar-2-pivot", wizard)
    if not shots.wanted(*PHASES["trocar"][2:]):
        return wizard.reject()
    wizard.back()
    wizard.method_page.tissue_button.setChecked(True)
    wizard.next()
    page = wizard.tissue_page
    wait_until(lambda: len(page.samples) >= 3, FEED_TIMEOUT_S, "the tissue page's first samples")
    shots.shoot("trocar-2-tissue", wizard)
    wizard.back()
    wizard.method_page.arc_button.setChecked(True)
    wizard.next()
    shots.shoot("trocar-3-arc", wizard)
    wizard.back()
    wizard.method_page.manual_button.setChecked(True)
    wizard.next()
    shots.shoot("trocar-4-manual", wizard)
    wizard.next()
    shots.shoot("trocar-5-summary", wizard)
    wizard.button(QWizard.WizardButton.FinishButton).click()
    wait_until(lambda: window.wizards.active is None, 60, "the trocar wizard to save and finish")
    _shoot_calibration_box(shots, window, "trocar-6-applied")


def _refusal_and_close(shots: Shooter, window) -> None:
    screen = window.acquisition                      # a new screen since acquisition restarted
    window.rig._simulator.kill()                     # the IMU unplugged: its samples stop
    wait_until(lambda: "IMU is stale" in screen.store_reason.text(), 60, "the IMU to go stale")
    screen.request_store("F5")                       # the foot pedal
    wait_until(lambda: screen.store_status.text().startswith("Refused (F5)"), 10, "the refusal")
    shots.shoot("refused-store", window)
    window.close()
    wait_until(lambda: window.close_prompt is not None, 10, "the question on close")
    shots.shoot("close-question", window, box=window.close_prompt)
    [keep] = [b for b in window.close_prompt.buttons() if b.text() == "Keep recording"]
    keep.click()


def open_review(window, timeout_s: float = 120.0):
    """The window's recorded session closed and opened in its Review tab (the first call; later ones show the tab),
    once read: its nodes listed, the IMU fused, its video opened. Returns the review screen; SystemExit naming what
    did not come after ``timeout_s`` (the layout tests open the review the same way)."""
    if window.session is not None:
        path = window.session.path
        window.pause_acquisition()
        window.session.close()
        window.session = None
        window.open_for_review(path)
    review = window.review
    window.tabs.setCurrentWidget(review)
    wait_until(lambda: review.node_table.rowCount() > 0 and not review.status.text().startswith(("loading", "fusing")),
               timeout_s, "the review")
    wait_until(lambda: review.scrubber.video is not None, timeout_s, "the review's video")
    return review


def _review(shots: Shooter, window) -> None:
    path = window.session.path
    review = open_review(window)
    review.node_table.selectRow(1)                   # its recorded pair at the store fills the two feeds
    wait_until(lambda: review.snapshots.left_view.title.startswith("left: frame"), 60, "the node's recorded pair")
    shots.shoot("tab-3-review", window)
    if shots.wanted(*PHASES["replay"]):
        window.replay(path, 1.0)                     # the session just recorded, played back into a new one
        window.tabs.setCurrentWidget(window._acquisition_tab)
        wait_until(lambda: window.acquisition.nodes.rowCount() == 0 and window.acquisition._last_result is not None,
                   120, "the replay's first frame")
        spin(3.0)
        shots.shoot("replay-acquisition", window)


def _size(text: str) -> tuple[int, int]:
    width, height = text.lower().split("x")
    return int(width), int(height)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snreg_gui.screenshots", description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="screenshots", help="folder for the PNG files")
    parser.add_argument("--sizes", default=",".join(f"{w}x{h}" for w, h in SIZES),
                        help="window sizes, e.g. 1024x700,1920x1080")
    parser.add_argument("--only", default="", help="comma-separated parts of shot names (e.g. trocar,tab-1)")
    parser.add_argument("--camera", choices=("surgery", "still"), default="surgery",
                        help="the demo shown: surgery (the camera moves between nodes) or still (the thesis' phantom)")
    parser.add_argument("--docs", action="store_true",
                        help="the technician's guide's set: tabs at every size, wizard pages at the first, 256 colours")
    args = parser.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    app = QApplication.instance() or QApplication(sys.argv[:1])
    shots = Shooter(out, [_size(s) for s in args.sizes.split(",")], [p for p in args.only.split(",") if p], args.docs)
    from snreg.demo.rig import DemoRig
    from snreg.demo.scene import Schedule
    from snreg_gui.app import MainWindow

    work = Path(tempfile.mkdtemp(prefix="snreg-screens-"))     # the demo session, its video and SPECT: removed
    settings = QSettings(str(work / "settings.ini"), QSettings.Format.IniFormat)
    # the still phantom rests 60 frames per node (a short run); the surgery camera's tour follows its IMU's real-time
    # motion, so it keeps the rests a person gets, rendered at a quarter of the thesis resolution and a node stored
    # from fewer fixes (at half the resolution and 60 fixes a loaded machine stored no node in 15 minutes)
    if args.camera == "surgery":
        window = MainWindow(str(work / "demo.h5"), demo=True, rig=DemoRig(camera="surgery", scale=SURGERY_SCALE),
                            settings=settings, fixes_per_node=SURGERY_FIXES)
    else:
        window = MainWindow(str(work / "demo.h5"), demo=True, rig=DemoRig(schedule=Schedule(rest_frames=60)),
                            settings=settings)
    window.resize(*shots.sizes[0])
    window.show()
    try:
        stored = shots.wanted(*PHASES["tabs"], *PHASES["refusal"], *PHASES["navigation"])
        if stored:
            _store_and_register(shots, window)
        if shots.wanted(*PHASES["stereo"]):
            _stereo_wizard(shots, window)
        if shots.wanted(*PHASES["trocar"]):
            _trocar_wizard(shots, window)
        if shots.wanted(*PHASES["refusal"]):
            _refusal_and_close(shots, window)
        if stored and shots.wanted("tab-3-review", *PHASES["replay"]):
            _review(shots, window)
    finally:
        window._end_confirmed = True              # no question on close: the run is over
        window.shutdown()
        app.processEvents()
        settings.sync()          # written now, so nothing rewrites the folder once it is deleted
        shutil.rmtree(work, ignore_errors=True)
    print(f"{len(shots.written)} screenshots in {out}; {len(shots.blank)} blank; {len(shots.missed)} not taken",
          flush=True)
    for reason in shots.missed:
        print(f"not taken: {reason}", file=sys.stderr)
    for reason in shots.blank:
        print(f"blank: {reason}", file=sys.stderr)
    return 1 if shots.blank or not shots.written else 0
