"""The rig: the devices of one set-up behind the :class:`Rig` and :class:`Imu` protocols, the hardware rig and the
technician's choice of devices (:class:`RigConfig`). The demo rig, in :mod:`snreg.demo.rig`, answers the same
protocols."""

from snreg.rig.config import CAMERA_MODES, RigConfig
from snreg.rig.hardware import ABSENT, AbsentImu, HardwareRig, check_source, open_frame_source
from snreg.rig.protocols import Imu, Rig

__all__ = ["Rig", "Imu", "RigConfig", "CAMERA_MODES", "HardwareRig", "AbsentImu", "ABSENT", "check_source",
           "open_frame_source"]
