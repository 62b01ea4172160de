"""Issue 35: the demo's technician holds the probe on a node until it is stored. The tour's clock (HeldTour) over a
motion timeline, and the simulated IMU playing the same timeline (its rests held, its moves in step)."""

import math

import numpy as np
import pytest

from snreg.cli import main
from snreg.demo.held_tour import HeldTour
from snreg.demo.imu_motion import MotionProfile, rotate, still
from snreg.demo.imu_simulator import ImuSimulator, SensorModel
from snreg.demo.motion_timeline import MotionTimeline, Run

FPS = 10.0


def test_a_timeline_runs_with_the_clock_holds_at_its_stop_and_skips_ahead_when_a_run_says_so():
    timeline = MotionTimeline(Run(0.0, 0.0, 3.0))
    np.testing.assert_allclose(timeline.motion_s([-1.0, 0.0, 2.0, 3.0, 5.0]), [-1.0, 0.0, 2.0, 3.0, 3.0])
    np.testing.assert_allclose(timeline.rate([-1.0, 2.0, 4.0]), [1.0, 1.0, 0.0])
    timeline.add(Run(6.0, 3.0, 10.0))                       # held 3 s, then on until 10
    np.testing.assert_allclose(timeline.motion_s([5.9, 6.0, 8.0, 20.0]), [3.0, 3.0, 5.0, 10.0])
    timeline.add(Run(7.0, 10.0))                            # a release before the stop: skips ahead to it
    np.testing.assert_allclose(timeline.motion_s([6.5, 7.0, 9.0]), [3.5, 10.0, 12.0])
    with pytest.raises(ValueError, match="before the one before it"):
        timeline.add(Run(6.5, 0.0))


def test_a_run_is_one_line_the_simulator_reads_back_and_a_bad_line_says_what_it_needs():
    for run in (Run(1.5, 0.25, 3.0), Run(2.0, 1.0)):
        assert Run.parse(run.line()) == run and run.line().endswith("\n")
    assert Run.parse(Run(2.0, 1.0).line()).until_s == math.inf
    with pytest.raises(ValueError, match="three numbers, START FROM UNTIL"):
        Run.parse("1 2")
    timeline = MotionTimeline(Run(0.0, 0.0, 1.0))
    timeline.follow(iter([Run(2.0, 1.0, 4.0).line(), "\n", "garbage\n", Run(9.0, 4.0).line()]))
    assert timeline.last == Run(2.0, 1.0, 4.0)             # a broken sender: the motion holds where it stopped


def tour(**options) -> HeldTour:
    """Two rests of 10 frames (0-9, 15-24) in a tour of 30 frames at 10 fps."""
    return HeldTour([(0, 10), (15, 10)], 30, FPS, **options)


def test_a_rest_holds_at_its_end_until_released_and_the_probe_lifts_lead_frames_later():
    sent = []
    clock = tour(lead_frames=3, send=sent.append)
    assert [clock.tour_frame(k) for k in range(12)] == list(range(10)) + [9, 9]       # held on its last frame
    assert clock.release(12) and not clock.release(13)      # a second store on the same rest changes nothing
    assert [clock.tour_frame(k) for k in range(12, 20)] == [9, 9, 9, 9, 10, 11, 12, 13]
    assert not clock.release(18)                            # moving: nothing to release
    assert sent == [Run(0.0, 0.0, 0.9), Run(1.5, 0.9, 2.4)]   # each run told (in seconds), the first at once


def test_a_store_early_in_a_rest_ends_it_early_and_one_seen_late_never_ends_the_next_rest():
    clock = tour(lead_frames=0)
    assert clock.release(3)                                 # stored on the rest's 4th frame: the move starts now
    assert [clock.tour_frame(k) for k in (3, 4, 5)] == [9, 10, 11]
    assert clock.tour_frame(12) == 18 and clock.resting(18)
    assert not clock.release(2, now_index=12)               # frame 2 showed the first rest, already released
    assert clock.release(12) and clock.tour_frame(13) == 25


def test_nobody_storing_the_rest_moves_on_after_the_maximum_hold_counted_in_frames_delivered():
    clock = tour(max_hold_frames=20)
    delivered = list(range(9)) + list(range(10, 100, 3))        # a loaded computer: every third frame from frame 10
    for k in delivered:
        clock.shown_frame(k)
    held = [k for k in delivered if clock.tour_frame(k) == 9]
    assert len(held) == 20 and held[-1] >= 60                  # 20 delivered while held: 60 frames of wall clock
    assert clock.tour_frame(held[-1] + 1) == 10


def test_a_held_rest_shows_fresh_exposures_of_the_same_rest_and_timed_rests_ignore_releases():
    clock = tour()
    shown = [clock.shown_frame(k) for k in range(40, 60)]   # held on the first rest's end
    assert all(0 <= s < 10 for s in shown) and len(set(shown)) == 10
    timed = tour(held=False)
    assert [timed.tour_frame(k) for k in (0, 9, 10, 31)] == [0, 9, 10, 31] and not timed.release(5)
    assert [timed.shown_frame(k) for k in (3, 33)] == [3, 33]


def test_the_simulated_imu_holds_where_its_timeline_holds_and_moves_in_step_after():
    """A 20 deg turn over 2 s from second 1; the timeline holds the start of the turn from 1 s to 3 s: the sensor
    reads the same gravity and no rate meanwhile, then the turn 2 s late, sample for sample."""
    profile = MotionProfile([still(1.0), rotate((0.0, 0.0, 1.0), 20.0, 10.0), still(1.0)])
    exact = SensorModel(accel_noise_density_g=0.0, gyro_noise_density_dps=0.0, gyro_bias_max_dps=0.0,
                        accel_range_g=None, gyro_range_dps=None)
    timeline = MotionTimeline(Run(0.0, 0.0, 1.0))
    timeline.add(Run(3.0, 1.0))
    held = ImuSimulator(profile, rate_hz=100.0, sensor=exact, timeline=timeline).readings(500)
    free = ImuSimulator(profile, rate_hz=100.0, sensor=exact).readings(500)
    assert np.abs(held.gyro_dps[100:300]).max() < 1e-9                     # held: no rate
    np.testing.assert_allclose(held.accel_g[100:300], held.accel_g[[100] * 200], atol=1e-12)
    np.testing.assert_allclose(held.gyro_dps[300:500], free.gyro_dps[100:300], atol=1e-9)
    np.testing.assert_allclose(held.accel_g[300:500], free.accel_g[100:300], atol=1e-12)
    assert np.abs(free.gyro_dps[150:250, 2]).max() > 10.0                # the turn itself


def test_the_timeline_channel_needs_a_motion(capsys):
    assert main(["imu", "simulate", "--still", "--timeline-stdin"]) == 2
    assert "--timeline-stdin paces the motion of --motion FILE" in capsys.readouterr().err
