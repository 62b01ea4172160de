"""The preop box's landmarks: read with the nodes, or from a file of their own ("Landmarks..."), cleared by hand.

Why: a radiologist places the anatomical landmarks (issue 29) on the CT in 3D Slicer and saves them apart, as a
``.mrk.json`` (RAS or LPS); a SPECT loaded in the box gives none. The landmarks stay until replaced, because they
belong to the case, not to one segmentation: re-segmenting with the slider, reading the SPECT again or a node file
without landmarks keeps them; a node file with landmarks of its own replaces them (the status says so); "clear"
forgets them; a session's stored preop set brings its own (none: none). The file is read in a worker by
:func:`snreg.workflow.preop_landmarks.read_preop_landmarks` (the rules of ``snreg register --preop-landmarks``: in
patient LPS like the SPECT's nodes, names as snreg keeps them, another frame refused); a bad file is said in one
sentence and changes nothing. A mixin of :class:`~snreg_gui.registration.preop.PreopSourceBox`: it emits
``landmarks_changed`` after a landmark file or a clear (the panel saves the preop set with them, the app sends them on
the live link).
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtWidgets import QHBoxLayout, QPushButton

from snreg.nodes import NodeSet
from snreg.workflow.preop_landmarks import read_preop_landmarks
from snreg_gui.common import file_places
from snreg_gui.common.workers import sentence

LANDMARK_FILTER = "Landmark files (*.mrk.json *.json *.csv)"


def plural(n: int, word: str) -> str:
    return f"{n} {word}{'s' * (n != 1)}"


class BoxLandmarks:
    """The box's landmarks (module docstring): ``landmarks`` (ids = names, LPS mm; None: none) and where they came
    from (``landmark_source``: a file's name, or the session)."""

    landmarks: NodeSet | None = None
    landmark_source = ""
    _marks_generation = 0
    marks_reading = False        # a landmark file is being read
    _replaced = ""               # what the last node file's landmarks replaced, said once in the status

    def _landmark_controls(self) -> QHBoxLayout:
        self.landmarks_button = QPushButton("Landmarks...")
        self.landmarks_button.setToolTip("read the anatomical landmarks placed on the CT (a 3D Slicer point list, "
                                         "RAS or LPS, or a CSV of landmarks); they replace those shown")
        self.clear_landmarks_button = QPushButton("clear")
        self.clear_landmarks_button.setToolTip("forget the preop landmarks")
        self.clear_landmarks_button.setEnabled(False)
        self.landmarks_button.clicked.connect(self._choose_landmark_file)
        self.clear_landmarks_button.clicked.connect(self.clear_landmarks)
        row = QHBoxLayout()
        row.addWidget(self.landmarks_button)
        row.addWidget(self.clear_landmarks_button)
        row.addStretch(1)
        return row

    # -- public --------------------------------------------------------------
    def load_landmarks(self, path) -> None:
        """Read a file of preop landmarks in a worker; they replace the landmarks shown (the nodes stay)."""
        self._marks_generation += 1
        self.marks_reading = True
        self.status.setText(f"reading landmarks from {Path(path).name}...")
        self._tasks.start(self._read_landmarks, self._marks_generation, str(path),
                          returned=self._landmarks_read, errored=self._landmarks_failed)

    def clear_landmarks(self) -> None:
        """Forget the preop landmarks (the nodes stay)."""
        self._marks_generation += 1
        self._replaced, self.marks_reading = "", False
        self._set_landmarks(None, "")
        self.landmarks_changed.emit(None)

    # -- internals -----------------------------------------------------------
    @staticmethod
    def _read_landmarks(generation: int, path: str) -> tuple[int, NodeSet, str]:
        return generation, read_preop_landmarks(path), Path(path).name

    def _choose_landmark_file(self) -> None:
        path = file_places.choose_file(self, "Preop landmarks (placed on the CT)", self.session, LANDMARK_FILTER)
        if path:
            self.load_landmarks(path)

    def _landmarks_read(self, read: tuple[int, NodeSet, str]) -> None:
        generation, marks, source = read
        if generation != self._marks_generation:       # a newer read or a clear since
            return
        self.marks_reading = False
        self._replaced = ""
        self._set_landmarks(marks, source)
        self.landmarks_changed.emit(self.landmarks)

    def _landmarks_failed(self, message: str) -> None:
        self.marks_reading = False
        self.status.setText(sentence(message))

    def _set_landmarks(self, marks: NodeSet | None, source: str) -> None:
        self.landmarks = marks if marks is not None and len(marks) else None
        self.landmark_source = source if self.landmarks is not None else ""
        self.clear_landmarks_button.setEnabled(self.landmarks is not None)
        self._show_status()

    def _take_landmarks(self, marks: NodeSet | None, source: str, replace: bool) -> None:
        """Landmarks that came with nodes from ``source``: any replace those shown (said once); none keep them unless
        ``replace`` (a session's stored set: its own or none)."""
        self._replaced = ""
        if marks is not None and len(marks):
            if self.landmarks is not None and self.landmark_source != source:
                self._replaced = f"{plural(len(self.landmarks), 'landmark')} from {self.landmark_source}"
        elif not replace:
            marks, source = self.landmarks, self.landmark_source
        self._set_landmarks(marks, source)

    def _landmark_text(self, node_source: str) -> str:
        """"; 3 landmarks from Y" (with what they replaced), or "" without landmarks or when they came with the nodes
        (the node text says them then)."""
        if self.landmarks is None or (self.landmark_source == node_source and self._volume is None
                                      and self.nodes is not None):
            return ""
        return f"; {plural(len(self.landmarks), 'landmark')} from {self.landmark_source}"
