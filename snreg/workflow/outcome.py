"""What the acquisition gives per pair (:class:`FrameOutcome`) and what it is given with each pair besides the images
(:class:`ImuReading`): the data contract between :class:`~snreg.workflow.acquisition.Acquisition` and those who show
or stream its results (the app's worker, ``snreg demo --headless``, the live link)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from snreg.imu.protocol import ImuSample
from snreg.sources import StereoFrame
from snreg.tracking import ProbeFix
from snreg.workflow.insertion import InsertionStep
from snreg.workflow.store_guard import StoreCheck

__all__ = ["FrameOutcome", "ImuReading"]


@dataclass(frozen=True, eq=False)
class FrameOutcome:
    """What one pair gave: the fix (None with the ``reason``), the tip in the trocar frame (mm), and the store
    window: how many valid fixes it holds (at most N), their spread (mm, NaN until full), whether that is still,
    and whether the auto-store rule (full, still, and over ``AUTO_STORE_SEPARATION_MM`` from every stored node) would store it now.
    ``trocar_from_probe`` (4, 4): the probe pose at the frame's IMU orientation (tip, axis backwards as z), None without
    a fix; the live link to 3D Slicer streams it. ``store_check``: what Store SN would meet now (the guard's
    refusal in words, or the near node to confirm); ``imu_gap_s``: from the frame's grab time to the nearest IMU
    sample; ``video``: the recording's state in words (:func:`~snreg.session.video.video_text`). With insertion
    tracking: ``insertion``, the tracker's estimate at this pair and the insertion the pair was mapped with (held from
    the last tracked pair when lost), ``insertion_text`` in words (:func:`~snreg.workflow.insertion.insertion_text`) and ``insertion_ms``
    what it adds to the pair's time (its images are made beside the probe tracker); None, "" and 0 without."""

    index: int
    fix: ProbeFix | None
    reason: str
    tip_trocar: np.ndarray | None
    valid_fixes: int
    window_spread_mm: float
    still: bool
    auto_store_due: bool
    track_ms: float
    trocar_from_probe: np.ndarray | None = None
    store_check: StoreCheck = StoreCheck("waiting for the first frame")
    imu_gap_s: float = 0.0
    video: str = ""
    insertion: InsertionStep | None = None
    insertion_text: str = ""
    insertion_ms: float = 0.0


@dataclass(frozen=True)
class ImuReading:
    """The endoscope orientation at a frame's grab time: ``earth_from_imu`` (3, 3), how far (s) the nearest IMU
    sample is from that time (``gap_s``), the IMU's ``state``, and the raw samples since the last frame."""

    earth_from_imu: np.ndarray
    samples: Sequence[ImuSample] = ()
    gap_s: float = 0.0
    state: str = "open"

    @classmethod
    def at_frame(cls, imu, frame: StereoFrame) -> "ImuReading":
        """From an :class:`~snreg.rig.protocols.Imu`: the orientation interpolated at the frame's left grab time,
        and the samples it received since the last call."""
        at = imu.orientation_at(frame.t_left_ns)
        return cls(at.earth_from_imu, imu.take_samples(), at.gap_s, at.state)
