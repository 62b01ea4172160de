"""The recorded video of a session for review: the pair shown at a moment, with the probe overlay as tracked then.

Why: a reviewer scrubbing the timeline wants to see what the cameras saw between the stores, and whether the
tracker found the probe there. Qt-free: the review screen calls :meth:`ReviewVideo.frame_at` in a worker (a decode
takes tens of ms) and draws what it returns. One object is used by one thread at a time.

>>> video = ReviewVideo.open("s.h5")          # None when the session recorded no video
>>> shown = video.frame_at(12.5)              # seconds from the review origin (SessionReview.t0_ns)
>>> shown.left_rgb, shown.overlay_left        # (H, W, 3) RGB; (2, 2) pixels of the tip and a point up the axis
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from snreg.session.reader import readable_rows
from snreg.session.session import Session
from snreg.session.video import RecordedPairs, VideoSegment

AXIS_DRAWN_MM = 50.0        # the overlay's axis, as the acquisition screen draws it


@dataclass(frozen=True, eq=False)
class ReviewFrame:
    """The pair of frame row ``row`` (RGB), its time (s from the review origin), the overlay (None without a fix)."""

    row: int
    t_s: float
    left_rgb: np.ndarray
    right_rgb: np.ndarray
    overlay_left: np.ndarray | None
    overlay_right: np.ndarray | None


class ReviewVideo:
    """Frames of a recorded session by time, with the probe fixes of their rows projected onto them."""

    def __init__(self, path: Path, segments: list[VideoSegment], frame_ns: np.ndarray, probe: np.ndarray,
                 calibration, t0_ns: int):
        self.path, self._frame_ns, self._t0 = path, frame_ns, int(t0_ns)
        self._probe = {int(t): (tip, axis) for t, tip, axis in zip(probe["t_host_ns"], probe["tip_mm"], probe["axis"])}
        self._calibration = calibration
        self._pairs = RecordedPairs(path, segments)

    @classmethod
    def open(cls, path: str | Path, t0_ns: int) -> "ReviewVideo | None":
        """The session's video (None when it has none); ``t0_ns``: the review's time origin."""
        with Session.open(path) as session:
            segments = session.videos()
            if not segments:
                return None
            frames, probe = (_rows(session.stream(name)) for name in ("frames", "probe"))
            calibration = session.calibration().get("stereo")
        return cls(Path(path), segments, np.asarray(frames["t_host_ns"], dtype=np.int64), probe, calibration, t0_ns)

    @property
    def times_s(self) -> np.ndarray:
        """Each frame row's time (s from the review origin)."""
        return (self._frame_ns - self._t0) / 1e9

    def row_at(self, t_s: float) -> int:
        """The frame row shown at ``t_s``: the last one at or before it (the first before the first)."""
        return int(np.clip(np.searchsorted(self.times_s, t_s, side="right") - 1, 0, len(self._frame_ns) - 1))

    def frame_at(self, t_s: float) -> ReviewFrame | None:
        """The pair shown at ``t_s`` with its overlay; None when that row has no frame in the video."""
        if not len(self._frame_ns):
            return None
        row = self.row_at(t_s)
        pair = self._pair(row)
        if pair is None:
            return None
        overlays = self._overlays(int(self._frame_ns[row]))
        return ReviewFrame(row, float(self.times_s[row]), cv2.cvtColor(pair[0], cv2.COLOR_BGR2RGB),
                           cv2.cvtColor(pair[1], cv2.COLOR_BGR2RGB), *overlays)

    def _overlays(self, t_ns: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        fix = self._probe.get(t_ns)
        if fix is None or self._calibration is None:
            return None, None
        tip, axis = (np.asarray(v, dtype=float) for v in fix)
        points = np.array([tip, tip + AXIS_DRAWN_MM * axis])
        c = self._calibration
        out = []
        for rvec, tvec, K, D in ((np.zeros(3), np.zeros(3), c.K1, c.D1),
                                 (cv2.Rodrigues(np.asarray(c.R, dtype=float))[0].ravel(),
                                  np.asarray(c.T, dtype=float).ravel(), c.K2, c.D2)):
            pixels, _ = cv2.projectPoints(points, rvec, tvec, np.asarray(K, dtype=float), np.asarray(D, dtype=float))
            out.append(pixels.reshape(2, 2))
        return out[0], out[1]

    def _pair(self, row: int) -> tuple[np.ndarray, np.ndarray] | None:
        try:
            return self._pairs.pair(row)
        except OSError:
            return None

    def close(self) -> None:
        self._pairs.close()


def _rows(stream) -> np.ndarray:
    return readable_rows(stream) if hasattr(stream, "id") else np.asarray(stream)
