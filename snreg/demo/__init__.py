"""The hardware-free phantom demo (thesis §4.2 phantom experiment): rendered feeds, simulated IMU, synthetic SPECT."""
