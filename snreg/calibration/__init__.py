"""Camera and trocar calibration (thesis §3.5, §4.1-4.2) and the versioned calibration file."""

from snreg.calibration.files import CalibrationFileError, StereoCalibration, load_calibration, thesis_calibration

__all__ = ["StereoCalibration", "CalibrationFileError", "load_calibration", "thesis_calibration"]
