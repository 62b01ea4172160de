"""Camera and trocar calibration (thesis §3.5, §4.1-4.2): checkerboards, stereo calibration, pivot and trocar methods.

The calibration file itself and :class:`~snreg.camera.StereoCalibration` are core types in :mod:`snreg.camera`.
"""
