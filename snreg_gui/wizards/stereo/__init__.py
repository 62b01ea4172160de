"""The checkerboard stereo calibration wizard: live capture with coverage, calibration with per-view errors, save."""
