"""The acquisition settings the operator chooses, remembered between runs (QSettings): the store guard's spread limit
(set on the acquisition screen), recording the video and tracking the camera's insertion (Devices menu; only on a
rig whose camera slides in a trocar: the demo phantom's does not, nor a replay of a session recorded without it).

Why one place: each is read when the acquisition worker starts, and a change of the two switches restarts it; the
window only wires them (the keys are also what ``python -m snreg_gui.bench`` sets).
"""

from __future__ import annotations

from PySide6.QtCore import QObject, QSettings, Signal
from PySide6.QtGui import QAction

from snreg.demo.replay import ReplayRig
from snreg.workflow.acquisition import StoreLimits

MAX_SPREAD_KEY = "acquisition/max_spread_mm"            # the store guard's spread limit (default 2 mm)
RECORD_VIDEO_KEY = "acquisition/record_video"           # both feeds recorded beside the session (default on)
TRACK_INSERTION_KEY = "acquisition/track_insertion"     # the camera's insertion followed from the video (default on)

_SAID = {  # (key, on): what the status bar says after the switch
    (RECORD_VIDEO_KEY, True): "both feeds are recorded with the session",
    (RECORD_VIDEO_KEY, False): "video recording is off: the session keeps only two snapshots per node",
    (TRACK_INSERTION_KEY, True): "the camera's insertion is tracked from the video: each node is mapped where the "
                                 "camera is when it is stored",
    (TRACK_INSERTION_KEY, False): "insertion tracking is off: every node is mapped at the trocar calibration's "
                                  "distance, and a slide of the camera goes unseen",
}


class AcquisitionOptions(QObject):
    """``record_video`` and ``track_insertion``: checkable actions for the Devices menu, on by default; a toggle is
    remembered and emits ``switched(sentence)`` (the window restarts the acquisition and shows the sentence)."""

    switched = Signal(str)

    def __init__(self, settings: QSettings, parent: QObject | None = None):
        super().__init__(parent)
        self._settings = settings
        self.record_video = self._switch("Record video with the session", RECORD_VIDEO_KEY,
                                         "both feeds recorded beside the session (off: two snapshots per node)")
        self.track_insertion = self._switch(
            "Track the camera's insertion", TRACK_INSERTION_KEY,
            "follow the camera sliding in the trocar from the video, the IMU and the pivot, and map each node where "
            "the camera is (off: the trocar calibration's distance throughout)")

    def _switch(self, text: str, key: str, tip: str) -> QAction:
        action = QAction(text, self, checkable=True)
        action.setChecked(self._settings.value(key, True, type=bool))
        action.setToolTip(tip)
        action.setStatusTip(tip)
        action.toggled.connect(lambda on: self._switched(key, on))
        return action

    def _switched(self, key: str, on: bool) -> None:
        self._settings.setValue(key, bool(on))
        self.switched.emit(_SAID[key, bool(on)])

    def tracks_insertion(self, rig) -> bool:
        """Whether acquisition on ``rig`` follows the camera's insertion: the switch is on and its camera slides."""
        return self.track_insertion.isChecked() and rig.moving_camera

    def untracked_text(self, rig) -> str:
        """What the acquisition screen says when the insertion is not tracked on ``rig``, and why."""
        if not rig.moving_camera and isinstance(rig, ReplayRig):
            return "camera insertion not tracked: the replayed session was recorded without it"
        if not rig.moving_camera:
            return "camera insertion not tracked: this rig's camera does not slide in a trocar"
        return ("camera insertion not tracked (Devices > Track the camera's insertion): nodes are mapped at the trocar "
                "calibration's distance")

    def limits(self) -> StoreLimits:
        """The store guard's limits with the spread limit chosen."""
        return StoreLimits(max_spread_mm=float(self._settings.value(MAX_SPREAD_KEY, StoreLimits.max_spread_mm)))

    def set_max_spread(self, mm: float) -> None:
        self._settings.setValue(MAX_SPREAD_KEY, float(mm))
