"""Probe tracking: stripe markers, stereo depth, and left/right frame pairing (thesis §3.4)."""

from snreg.tracking.pairing import SkewStats, StereoPairer
from snreg.tracking.smoothing import FixFilter, summarise
from snreg.tracking.stereo import ProbeFix, StereoTracker, TrackingError

__all__ = ["StereoPairer", "SkewStats", "ProbeFix",
           "StereoTracker", "TrackingError", "FixFilter", "summarise"]
