"""The endoscope's own motion: its insertion through the trocar from the stereo video, the IMU and the pivot.

:class:`InsertionTracker` follows ``trocar_camera_mm`` pair by pair (tracked with a quality, or lost with a
reason); :mod:`snreg.odometry.motion` holds the pivot-model and free motion fits it is made of, and
:mod:`snreg.odometry.held` how uncertain an insertion held while lost grows.
"""

from snreg.odometry.tracker import LOST, START_REASON, TRACKED, InsertionEstimate, InsertionTracker
from snreg.odometry.views import OdometryParams

__all__ = ["InsertionTracker", "InsertionEstimate", "OdometryParams", "TRACKED", "LOST", "START_REASON"]
