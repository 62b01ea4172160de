"""Where the registration panel's search starts: gravity (the default) or the typed initial alignment, and the
table's tilt.

Why: the technician cannot know the angles between the SPECT/CT frame and the trocar frame, but gravity is seen in
both (:mod:`snreg.workflow.registration_start`): the SPECT's patient position turned by the table's head-down tilt
(an operator setting, default 30 degrees, :mod:`snreg.preop.gravity`) and the IMU's down through the session's chain.
So the panel starts from gravity unless the operator types angles (an override, said so) or gravity cannot be known
(no patient position, a patient on their side, no chain, intraop nodes from a file...); then it says why in one
sentence and starts from the typed alignment (centroids matched), never silently. The start used is shown with the
result (:attr:`RunRecord.start`). The preop down (patient position and tilt, with the tilt's source: entered or
default) is saved with the preop nodes, so ``snreg register SESSION.h5`` and ``snreg session info`` find it.

:func:`choose_start` decides (no Qt); :class:`StartBox` is the widget; :class:`PanelStart` is the panel's part
(a mixin using ``start_box``, ``preop_box``, ``alignment``, ``_session``, ``_intraop``, ``_tasks``).

>>> choice = choose_start(True, PreopDown("HFS"), session, intraop_is_session=True)
>>> choice.words
'start: gravity, table tilt 30 deg head down (default), heading searched'
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial

from PySide6.QtCore import Signal
from PySide6.QtWidgets import QButtonGroup, QDoubleSpinBox, QGridLayout, QGroupBox, QLabel, QRadioButton

from snreg.errors import PreopError, SessionError
from snreg.preop.gravity import MAX_TILT_DEG, TABLE_TILT_DEG, PreopDown
from snreg.workflow.registration_run import RunRecord, RunRequest, run_registration, save_preop
from snreg.workflow.registration_start import GravityStart, session_gravity
from snreg_gui.common.workers import sentence
from snreg_gui.registration.node_sets import has_nodes

TYPED_WORDS = "start: the typed initial alignment"
OVERRIDE_WORDS = f"{TYPED_WORDS} (its angles override gravity)"


@dataclass(frozen=True, eq=False)
class StartChoice:
    """The start a run will use: ``gravity`` (None: the typed alignment), ``words`` as the result shows them, and
    ``problem``: why gravity could not be used ("" when it is, or when the operator chose the typed alignment)."""

    gravity: GravityStart | None
    words: str
    problem: str = ""

    @property
    def status(self) -> str:
        """One sentence for the panel: the start, or why not gravity and what is used instead."""
        if self.problem:
            return (f"Gravity cannot give the start: {self.problem}; the typed alignment is used "
                    "(centroids matched, or the angles you type).")
        if self.gravity is None:
            return ("Your typed angles override gravity: the next run starts from the typed alignment (choose "
                    "gravity to go back).")
        return f"Next run's {self.words}."


def choose_start(use_gravity: bool, preop_down: PreopDown | None, session, intraop_is_session: bool) -> StartChoice:
    """The start for a run: gravity when ``use_gravity`` and both downs are known (``preop_down``: the preop nodes'
    patient position and the table's tilt, None when their source gave none; the intraop down from ``session``'s
    chain, only when the intraop nodes are that session's), else the typed alignment with the reason."""
    if not use_gravity:
        return StartChoice(None, OVERRIDE_WORDS)
    try:
        if preop_down is None:
            raise PreopError("the preop nodes carry no patient position (a SPECT without one, or a node file not "
                             "written from a SPECT by snreg preop)")
        if session is None:
            raise SessionError("no session is open, so gravity's direction in the trocar frame is unknown")
        if not intraop_is_session:
            raise SessionError("the intraop nodes come from a node file, which carries no down")
        gravity = session_gravity(session, preop_down)
    except ValueError as err:                          # PreopError, SessionError: one clause each
        reason = str(err).removeprefix(f"{getattr(session, 'path', '')}: ")
        return StartChoice(None, f"{TYPED_WORDS} (not gravity: {reason})", reason)
    return StartChoice(gravity, gravity.words)


def run_from(request: RunRequest, words: str) -> RunRecord:
    """Register as :func:`~snreg.workflow.registration_run.run_registration` does (worker thread), the record saying the
    start in ``words`` (why not gravity, when it was not)."""
    return replace(run_registration(request), start=words)


class StartBox(QGroupBox):
    """Start from gravity or the typed alignment, the table's head-down tilt (0 to 60 deg), and ``status``: a line
    saying which start the next run uses (the panel shows it beside Run); ``changed`` when the choice or the tilt
    changes."""

    changed = Signal()

    def __init__(self, parent=None):
        super().__init__("Start", parent)
        self._entered = False
        self.gravity_radio = QRadioButton("gravity (SPECT patient position + IMU)")
        self.gravity_radio.setToolTip("down in the SPECT (its patient position turned by the table's tilt) matched to "
                                      "down in the trocar frame (the IMU through the chain); every heading searched")
        self.typed_radio = QRadioButton("typed alignment (below)")
        self.typed_radio.setToolTip("start from the angles and shift typed below (the centroids matched when "
                                    "untouched)")
        self.gravity_radio.setChecked(True)
        group = QButtonGroup(self)
        group.addButton(self.gravity_radio)
        group.addButton(self.typed_radio)
        self.tilt_spin = QDoubleSpinBox()
        self.tilt_spin.setRange(0.0, MAX_TILT_DEG)
        self.tilt_spin.setDecimals(1)
        self.tilt_spin.setSingleStep(1.0)
        self.tilt_spin.setSuffix(" deg")
        self.tilt_spin.setValue(TABLE_TILT_DEG)
        self.tilt_spin.setKeyboardTracking(False)
        self.tilt_spin.setToolTip(f"the operating table's head-down (Trendelenburg) tilt as the team set it, 0 to "
                                  f"{MAX_TILT_DEG:g} deg; snreg's default {TABLE_TILT_DEG:g} until you change it")
        self.status = QLabel("")          # laid out by the panel above Run, where it is always in sight
        self.status.setWordWrap(True)
        self.status.setToolTip("the start the next Run uses (the Start box in the settings column chooses it)")
        grid = QGridLayout(self)
        grid.addWidget(self.gravity_radio, 0, 0, 1, 3)
        grid.addWidget(self.typed_radio, 1, 0, 1, 3)
        grid.addWidget(QLabel("Table tilt (head down)"), 2, 0)
        grid.addWidget(self.tilt_spin, 2, 1)
        grid.setColumnStretch(2, 1)                 # the tilt stays beside its label in a narrow column
        self.gravity_radio.toggled.connect(self.changed)
        self.tilt_spin.valueChanged.connect(self._tilt_edited)

    @property
    def use_gravity(self) -> bool:
        return self.gravity_radio.isChecked()

    @property
    def tilt_entered(self) -> bool:
        """Whether the operator set the tilt (or it came entered with the preop nodes); else snreg's default."""
        return self._entered

    def use_typed(self) -> None:
        """The operator touched the typed alignment: it becomes the start (no-op when it is already)."""
        self.typed_radio.setChecked(True)

    def preop_down(self, read: PreopDown | None) -> PreopDown | None:
        """``read``'s patient position under the tilt shown (None when the preop source gave no position record)."""
        return None if read is None else PreopDown(read.patient_position, self.tilt_spin.value(), self._entered)

    def take_tilt(self, read: PreopDown | None) -> None:
        """Show the tilt that came entered with the preop nodes (a session's, a node file's); a default one leaves the
        operator's setting as it is."""
        if read is not None and read.tilt_entered:
            self.tilt_spin.blockSignals(True)
            self.tilt_spin.setValue(read.tilt_deg)
            self.tilt_spin.blockSignals(False)
            self._entered = True

    def show_choice(self, choice: StartChoice) -> None:
        self.status.setText(choice.status)

    def _tilt_edited(self, _value: float) -> None:
        self._entered = True
        self.changed.emit()


class PanelStart:
    """The registration panel's start (module docstring): which one the next run uses, and the preop down saved."""

    def _preop_down(self) -> PreopDown | None:
        return self.start_box.preop_down(self.preop_box.down)

    def _start_choice(self) -> StartChoice:
        """The start for the next run: gravity's intraop down is the session's only when the intraop nodes are the
        session's (not a node file opened beside it; none stored yet counts as the
        session's: its chain gives the down)."""
        return choose_start(self.start_box.use_gravity, self._preop_down(), self._session, self._intraop_from_session)

    def _show_start(self) -> None:
        self.start_box.show_choice(self._start_choice())

    def _start_changed(self) -> None:
        """Choice or tilt changed: the tilt (with its source) is kept with the preop nodes in the session."""
        self._save_preop(self.preop_box.nodes)
        self._inputs_changed()

    def _save_preop(self, nodes) -> None:
        """Save ``nodes`` and their down in a writable session (a worker; one write at a time, the latest last)."""
        if self._session is None or not self._session.writable or not has_nodes(nodes):
            return
        if self._saving_preop:
            self._save_again = True
            return
        self._saving_preop = True
        self._tasks.start(partial(save_preop, down=self._preop_down()), self._session, nodes,
                          self.preop_box.landmarks, returned=self._preop_saved, errored=self._preop_save_failed)

    def _preop_saved(self, problem: str) -> None:
        if problem:
            self._say(problem)
        self._preop_save_ended()

    def _preop_save_failed(self, message: str) -> None:
        self._say(sentence(message))
        self._preop_save_ended()

    def _preop_save_ended(self) -> None:
        self._saving_preop = False
        if self._save_again:
            self._save_again = False
            self._save_preop(self.preop_box.nodes)
