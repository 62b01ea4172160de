"""The surgery tour rendered in a process of its own (issue 36): the frames it sends are the ones the app would render,
ahead of where the play is, and the process ends with the app, even a killed one."""

import os

import numpy as np
import pytest

from conftest import parent_to_kill, poll, process_gone
from snreg.camera import thesis_calibration
from snreg.demo.render_process import TourRenderProcess
from snreg.demo.scene import Schedule
from snreg.demo.surgery_scene import SurgeryScene
from snreg.probe import default_probe_model


@pytest.fixture(scope="module")
def made():
    """A small tour at an eighth of the thesis resolution, the arguments it was made of and the scene, nothing
    rendered."""
    args = (thesis_calibration().scaled(0.125), default_probe_model(), Schedule(rest_frames=30, noise_variants=2))
    kwargs = {"seed": 3}
    return args, kwargs, SurgeryScene(*args, **kwargs)


def test_the_process_renders_the_frames_ahead_of_the_play_as_they_are_rendered_here(made):
    args, kwargs, scene = made
    start, within = scene.tour.rest_starts[1] - 8, 10          # eight moving frames, then the next rest
    process = TourRenderProcess(scene, args, kwargs, within)
    pid = process.pid
    try:
        process.follow(start)
        assert pid != os.getpid() and not process_gone(pid)
        assert poll(lambda: scene.pending(start, within) is None)
        assert scene.pending(scene.tour.rest_starts[2] - 5, 3) is not None     # nothing further than asked
        moving, rest = start + 3, scene.tour.rest_starts[1]
        assert scene.resting_node(moving) is None and scene.resting_node(rest) == 1
        np.testing.assert_array_equal(scene.render(moving)[0], scene.render_distinct(moving)[0])
        np.testing.assert_array_equal(scene.render(moving)[1], scene.render_distinct(moving)[1])
        here = scene.render_distinct(rest)
        for k in (0, 1, 2, 3):                                       # every pairing of the rest's exposures
            for a, b in zip(scene.render(rest + k), here.pair(rest + k)):
                np.testing.assert_array_equal(a, b)
    finally:
        process.close()
    assert process_gone(pid) and process.ended


KILLED_PARENT = """
import os, signal, sys
from snreg.camera import thesis_calibration
from snreg.demo.render_process import TourRenderProcess
from snreg.demo.scene import Schedule
from snreg.probe import default_probe_model

class Kept:
    def keep(self, key, rendered):
        print("kept", flush=True)

args = (thesis_calibration().scaled(0.125), default_probe_model(), Schedule(rest_frames=30, noise_variants=2))
rendering = TourRenderProcess(Kept(), args, {}, 1000)
print(rendering.pid, flush=True)
sys.stdin.readline()
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_killed_app_leaves_no_render_process(tmp_path):
    with parent_to_kill(KILLED_PARENT, tmp_path) as parent:
        pid = int(parent.stdout.readline())
        assert parent.stdout.readline().strip() == "kept"              # rendering when the app dies
        assert not process_gone(pid)
    assert poll(lambda: process_gone(pid))
