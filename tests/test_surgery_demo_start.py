"""The surgery demo's start-up (issue 35, item 9): the IMU is shown starting, not stale, before its first sample; the
rig says how far the tour's rendering has come; and the first frame comes once the IMU has started, while the tour
renders beside the feed as it plays, not after all of it."""

import re

import numpy as np
import pytest

from conftest import poll
from snreg.demo.rig import DemoRig
from snreg.demo.scene import Schedule
from snreg.imu.monitor import ImuSnapshot
from snreg_gui.acquisition.health import camera_health, imu_health
from snreg_gui.acquisition.status import BAD

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)

PROGRESS = re.compile(r"rendering the surgery tour, (\d+) of (\d+)")


def snapshot(state: str, samples: int, problem: str = "", age_s: float = float("inf")) -> ImuSnapshot:
    return ImuSnapshot(state, problem, 0.0, age_s, (0.0, 0.0, 0.0), np.eye(3), samples, 0)


@pytest.mark.parametrize("state", ["stopped", "connecting"])
def test_an_imu_with_no_sample_yet_is_starting_not_stale(state):
    assert imu_health(snapshot(state, 0)) == ("IMU: starting, no sample yet", "")


@pytest.mark.parametrize("imu", [snapshot("stale", 0, "no valid IMU sample for 1 s on /dev/x; check it"),
                                 snapshot("stopped", 500, age_s=3.0),
                                 snapshot("connecting", 0, "cannot open /dev/x: check the cable")])
def test_an_imu_that_stopped_or_failed_is_not_called_starting(imu):
    text, style = imu_health(imu)
    assert "starting" not in text
    assert (style == BAD) == imu.stale


def test_the_camera_line_says_what_the_rig_prepares():
    assert camera_health(None, float("inf"), preparing="rendering the surgery tour, 3 of 9") == (
        "camera: waiting for frames (rendering the surgery tour, 3 of 9)", "")
    assert camera_health(None, float("inf")) == ("camera: waiting for frames", "")


@pytest.mark.slow
def test_the_surgery_rig_starts_with_the_imu_starting_and_its_first_frame_before_the_tour_is_rendered():
    rig = DemoRig(scale=0.125, camera="surgery", seed=2)          # 6 s rests, as the app's
    try:
        assert imu_health(rig.imu.snapshot())[0] == "IMU: starting, no sample yet"      # before the first sample
        assert rig.preparing == "preparing the surgery tour" or PROGRESS.fullmatch(rig.preparing)
        source = rig.frame_source()
        assert rig.imu.snapshot().state != "stopped"              # the IMU started before the tour renders
        frame = source.read()
        rendered, total = rig.scene.rendered, rig.scene.distinct_frames
        # the tour renders as it plays: by the first frame no more than its first 10 s (no later rest)
        assert frame is not None and 1 <= rendered <= total - 9, (rendered, total)
        assert rig.imu.snapshot().samples > 0
        # and goes on beside the feed as it plays (each poll takes the next frame, as the acquisition does)
        assert poll(lambda: source.read() is not None and rig.scene.rendered > rendered, timeout_s=60.0)
        progress = PROGRESS.fullmatch(rig.preparing)              # "" only once the whole tour is rendered
        done, of = (int(progress.group(1)), int(progress.group(2))) if progress else (rig.scene.rendered, total)
        assert of == total and rendered < done <= total
        source.close()
    finally:
        rig.close()


class SilentImu:
    """An IMU whose port is open but has sent nothing yet."""

    def snapshot(self) -> ImuSnapshot:
        return snapshot("connecting", 0)


def test_the_screen_shows_the_tour_rendering_and_the_imu_starting(qtbot):
    from snreg_gui.acquisition.screen import AcquisitionScreen

    progress = ["rendering the surgery tour, 40 of 145"]
    screen = AcquisitionScreen(SilentImu(), fixes_per_node=5, preparing=lambda: progress[0])
    qtbot.addWidget(screen)
    qtbot.waitUntil(lambda: screen.video_health.text() == "camera: waiting for frames (rendering the surgery tour, "
                    "40 of 145)", timeout=3_000)
    assert screen.imu_health.text() == "IMU: starting, no sample yet"
    progress[0] = "rendering the surgery tour, 41 of 145"
    qtbot.waitUntil(lambda: "41 of 145" in screen.video_health.text(), timeout=3_000)
