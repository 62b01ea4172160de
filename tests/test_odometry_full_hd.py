"""The insertion tracker on full-HD pairs (1920x1080, the Firefly's and the thesis calibration's size): the path the
app runs, where the pair is reduced to a third (the working width, reduction factor 3), which the quarter-size renders
of the other odometry tests never take."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.camera import thesis_calibration
from snreg.demo.camera_path import CameraPath
from snreg.demo.surgery_video import SurgeryVideo, VideoOptions, surgery_chain
from snreg.demo.tissue import TissueScene, TissueSurface
from snreg.odometry import InsertionTracker
from snreg.probe import default_probe_model

START_MM = 158.0


@pytest.mark.slow
def test_full_hd_pairs_are_tracked_at_a_third_of_their_size_against_truth():
    calibration, probe, chain = thesis_calibration(), default_probe_model(), surgery_chain(START_MM)
    assert calibration.image_size == (1920, 1080)
    # slides of 4-5 mm and turns of up to 3 degrees between pairs, the probe in view, tissue no other test uses
    # (three pairs: rendering full HD is most of the test's time)
    insertions = np.array([START_MM, START_MM + 5.0, START_MM + 9.0])
    turns = Rotation.from_rotvec(np.radians([[0, 0, 0], [2.0, 1.0, 0], [3.5, 2.5, 0]]))
    path = CameraPath(insertions, turns, np.zeros(3))
    scene = TissueScene(calibration, probe, TissueSurface(depth_mm=240.0, seed=17, texture_seed=171))
    video = SurgeryVideo(scene, path, chain, VideoOptions(seed=17))
    tracker = InsertionTracker(calibration, chain, probe=probe)
    assert tracker.pair.factor == 3 and tracker.pair.size == (640, 360)
    estimates = [tracker.update(*video.pair(k), video.earth_from_imu(k), probe_fix=video.probe_pose(k))
                 for k in range(len(video))]
    assert all(e.tracked for e in estimates), [e.reason for e in estimates]
    errors = np.array([e.trocar_camera_mm - video.insertion_mm(e.index) for e in estimates])
    assert np.abs(errors).max() < 0.3, errors
    assert all(e.change_sd_mm < 0.3 and e.quality > 0.5 for e in estimates[1:])
    assert estimates[0].sd_mm == pytest.approx(tracker.start_sd_mm)
