"""Store landmark on the acquisition screen: the name picker beside Store SN, and what the screen does with a landmark.

Why: with fewer than three sentinel nodes the registration needs anatomical landmarks touched with the probe (issue
29). The technician holds the probe tip on the landmark and presses Store landmark: the same guards as Store SN (held
still, tracked, streams healthy), decided by the core (:meth:`snreg.workflow.acquisition.Acquisition.store_landmark`)
in the worker; its refusals, the override and the question (here: replace the landmark of that name?) come back as
Store SN's do. The name is picked from the preop landmarks first (the ones the CT has, so they pair), then the
vocabulary (:data:`snreg.landmarks.LANDMARKS`); the list is editable for any other anatomical name. A stored landmark
is listed marked "landmark" in the stored-nodes table, never counted as a node. A mixin of
:class:`~snreg_gui.acquisition.screen.AcquisitionScreen`, using its ``store_button``, ``nodes``, ``expected``,
``undo_button``, ``store_requested`` and its store state.
"""

from __future__ import annotations

from PySide6.QtCore import Signal
from PySide6.QtWidgets import QComboBox, QHBoxLayout, QPushButton, QSizePolicy, QWidget

from snreg.landmarks import LANDMARK, LANDMARKS
from snreg_gui.acquisition.status import GOOD
from snreg_gui.acquisition.worker import StoreRequest

NAME_HINT = "name"
LIST_PADDING_PX = 10         # each side of a name in the drop-down list


def is_landmark(node) -> bool:
    """Whether a stored point (an :class:`~snreg.session.IntraopNode`) is an anatomical landmark."""
    return getattr(node, "kind", "") == LANDMARK


def store_what(request: StoreRequest) -> str:
    """What a request's questions and refusals call the store: "Store landmark" or "Store SN"."""
    return "Store landmark" if request.landmark else "Store SN"


def near_title(request: StoreRequest) -> str:
    """The title of the question a store near a stored point (a landmark: one of its name) asks."""
    return "Store landmark: replace the one stored?" if request.landmark else "Store SN near a stored node"


class LandmarkPicker(QWidget):
    """An editable name list (the preop landmarks' names first, then the vocabulary) and the Store landmark button;
    ``requested()`` when pressed."""

    requested = Signal()

    def __init__(self, parent=None):
        super().__init__(parent)
        self.combo = QComboBox()
        self.combo.setEditable(True)
        self.combo.setInsertPolicy(QComboBox.InsertPolicy.NoInsert)
        self.combo.lineEdit().setPlaceholderText(NAME_HINT)
        self.combo.setToolTip("the landmark the probe tip is on: the CT's landmarks first (they pair by name), then "
                              "the usual ones; type another anatomical name if needed")
        self.combo.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)
        self.combo.setMinimumContentsLength(12)
        self.combo.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
        self.button = QPushButton("Store landmark")
        self.button.setToolTip("store the probe tip as this anatomical landmark (held still, tracked, as Store SN)")
        row = QHBoxLayout(self)
        row.setContentsMargins(0, 0, 0, 0)
        row.addWidget(self.combo, 1)
        row.addWidget(self.button)
        self.set_preop_names([])
        self.button.clicked.connect(self.requested)

    def set_preop_names(self, names) -> None:
        """Offer ``names`` (the preop landmarks') first, then the rest of the vocabulary; what was typed is kept."""
        typed = self.combo.currentText()
        first = list(dict.fromkeys(names))
        self.combo.blockSignals(True)
        self.combo.clear()
        self.combo.addItems(first)
        rest = [name for name in LANDMARKS if name not in first]
        if first and rest:
            self.combo.insertSeparator(len(first))
        self.combo.addItems(rest)
        self.combo.setEditText(typed if typed else (first[0] if first else ""))
        self.combo.blockSignals(False)
        view = self.combo.view()             # the list as wide as its longest name: never "right comm...ifurcation"
        widest = max((view.fontMetrics().horizontalAdvance(name) for name in self.offered()), default=0)
        view.setMinimumWidth(widest + 2 * LIST_PADDING_PX + view.verticalScrollBar().sizeHint().width())

    def offered(self) -> list[str]:
        """The names in the list, in order (separators left out)."""
        return [self.combo.itemText(k) for k in range(self.combo.count()) if self.combo.itemText(k)]

    def name(self) -> str:
        return self.combo.currentText().strip()


class LandmarkStoring:
    """The screen's Store landmark (module docstring)."""

    def set_landmark_names(self, landmarks) -> None:
        """The preop landmarks (a NodeSet, ids = names, or None): offered first in the name list."""
        self.landmark_picker.set_preop_names([] if landmarks is None else list(landmarks.ids))

    def request_landmark(self, trigger: str = "button") -> None:
        """Ask the worker to store the probe tip as the landmark named in the picker (the core checks the name and
        the guards); when nothing can be asked now (no frames, paused, a store pending) say so in red."""
        if not self.store_button.isEnabled():
            self.show_store_problem(f"Not stored ({trigger}): {self.store_button.toolTip()}.")
            return
        self._store_pending = True
        self._set_store_enabled(False, "storing...")
        self.store_requested.emit(StoreRequest("", trigger=trigger, landmark=self.landmark_picker.name()))

    def _add_landmark(self, node) -> None:
        """A landmark stored: listed marked (one that replaced another of its name takes its row), said in green."""
        self._store_pending = False
        self.nodes.remove(node.id)
        self.nodes.append(node)
        self.expected.set_node_ids(self._node_ids())
        self.undo_button.setEnabled(True)
        anyway = " anyway, the override on record" if self._overriding else ""
        self._overriding = False
        self._say(f"stored landmark {node.id!r}{anyway} (spread {node.spread_mm:.2f} mm over {node.n_frames} fixes)",
                  GOOD)
        self._update_store_state()
