"""The endoscope IMU (thesis §2.4, §5.3): serial line protocol, reader, simulator and orientation."""

from snreg.imu.fusion import Fusion, FusionStatus, fuse_arrays
from snreg.imu.motion import MotionProfile, Segment, protractor_profile, rotate, still
from snreg.imu.protocol import (CorruptLine, ImuSample, InfoLine, StreamCounts, StreamDecoder, format_info, format_line,
                                parse_line)
from snreg.imu.reader import ImuPortError, ImuState, SerialImuReader
from snreg.imu.simulator import CsvReplay, Faults, ImuSimulator, SensorModel, SimulatedPort

__all__ = ["CorruptLine", "ImuSample", "InfoLine", "StreamCounts", "StreamDecoder", "format_info", "format_line",
           "parse_line", "ImuPortError", "ImuState", "SerialImuReader", "Fusion", "FusionStatus", "fuse_arrays",
           "MotionProfile", "Segment", "protractor_profile", "rotate", "still", "CsvReplay", "Faults", "ImuSimulator",
           "SensorModel", "SimulatedPort"]
