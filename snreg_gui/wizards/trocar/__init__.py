"""The trocar calibration wizard: pivot method, thesis arc method, manual entry, summary saved into the session."""
