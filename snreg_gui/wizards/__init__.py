"""The device dialog and the calibration wizards (stereo checkerboard, trocar), and how the window opens them."""
