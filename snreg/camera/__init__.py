"""The stereo camera model everything uses (docs/design.md, Calibration file): :class:`StereoCalibration`, its
file (:mod:`snreg.camera.calibration`), and calibrations written by other tools (:mod:`snreg.camera.formats`)."""

from snreg.camera.calibration import (REQUIRED_KEYS, THESIS_CALIBRATION_PATH, CalibrationFileError, StereoCalibration,
                                      calibration_from_arrays, load_calibration, save_calibration, thesis_calibration)
from snreg.camera.formats import ImportedCalibration, import_calibration

__all__ = ["StereoCalibration", "CalibrationFileError", "load_calibration", "save_calibration", "thesis_calibration",
           "calibration_from_arrays", "import_calibration", "ImportedCalibration", "REQUIRED_KEYS",
           "THESIS_CALIBRATION_PATH"]
