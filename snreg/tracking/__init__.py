"""Probe tracking: stripe markers, stereo depth, and left/right frame pairing (thesis §3.4)."""

from snreg.tracking.pairing import SkewStats, StereoPairer
from snreg.tracking.probe_model import ProbeModel, default_probe_model, load_probe_model
from snreg.tracking.smoothing import FixFilter, summarise
from snreg.tracking.stereo import ProbeFix, StereoTracker, TrackingError

__all__ = ["StereoPairer", "SkewStats", "ProbeModel", "default_probe_model", "load_probe_model", "ProbeFix",
           "StereoTracker", "TrackingError", "FixFilter", "summarise"]
