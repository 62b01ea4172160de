"""The endoscope IMU (thesis §2.4, §5.3): serial line protocol, reader and orientation.

The simulated IMU (motion profiles, the LSM6DSOX model, the pseudo-terminal port) lives in :mod:`snreg.demo`.
"""

from snreg.imu.fusion import Fusion, FusionStatus, fuse_arrays
from snreg.imu.protocol import (CorruptLine, ImuSample, InfoLine, StreamCounts, StreamDecoder, format_info, format_line,
                                parse_line)
from snreg.imu.reader import ImuPortError, ImuState, SerialImuReader

__all__ = ["CorruptLine", "ImuSample", "InfoLine", "StreamCounts", "StreamDecoder", "format_info", "format_line",
           "parse_line", "ImuPortError", "ImuState", "SerialImuReader", "Fusion", "FusionStatus", "fuse_arrays"]
