"""The acquisition screen's expected errors: the SPECT nodes not found yet with their expected errors if registered
now, the nearest one's way from the tip, and which error source to improve.

Why: while nodes are stored the surgeon asks which SPECT nodes are still in and where; the answer is only as good as
the registration, so each comes with its expected error: how far (90 %) it may lie from where it is mapped if the
registration were run now ("P4 OBT R: expected within 6 mm (90 %)"; the Registration tab says where). The
registration panel registers again
in its worker after each store and hands over the hot spots it left unpaired with their 90 % bounds
(:meth:`ExpectedErrors.show_missing`); with fewer than 3 stored nodes, no SPECT or no current registration it hands
over none and nothing is said. When one source dominates the stored nodes' own covariances, the box says which and
what lowers it (:func:`snreg.workflow.error_advice.advice_text`, from each node's covariance by source). Each line is
hidden while it has nothing to say; no frame or heading of its own takes room from the side column (which must fit
700 px with three SPECT nodes missing: the guidance line below them says the way to the nearest, "P4: 47 mm, up and
left on screen, 12 mm deeper"). It computes nothing: the
lines are the core's.
"""

from __future__ import annotations

from PySide6.QtWidgets import QVBoxLayout, QWidget

from snreg.workflow.error_advice import advice_text
from snreg.workflow.guidance import targets_text
from snreg_gui.acquisition.status import StatusLine


class ExpectedErrors(QWidget):
    """``missing_list`` (the hot spots not found yet with their expected errors), ``guidance`` (the nearest one from
    the tip, live) and ``advice`` (the dominant error source). ``error_sources``: stored node id -> its covariance by
    source, a dict the window keeps (so it outlives a restart of the screen)."""

    def __init__(self, error_sources: dict | None = None):
        super().__init__()
        self.error_sources = {} if error_sources is None else error_sources
        self.missing: list = []
        self._node_ids: list[str] = []
        self.missing_list = StatusLine("", 1)
        self.guidance = StatusLine("", 1)
        self.advice = StatusLine("", 1)
        self.advice.setToolTip("the error source that dominates the stored nodes' own error (their covariances), "
                               "and what lowers it")
        layout = QVBoxLayout(self)
        layout.setContentsMargins(8, 0, 8, 0)         # in line with the group boxes' contents above
        layout.setSpacing(0)                  # the lines keep 4 px between them already
        for line in (self.missing_list, self.guidance, self.advice):
            layout.addWidget(line)
        self.setVisible(False)

    def show_missing(self, missing: list) -> None:
        """The SPECT nodes the latest registration left unpaired (:class:`~snreg.registration.report.MissingNode`),
        with their expected errors; [] says nothing (no registration answers the nodes stored now)."""
        self.missing = list(missing)
        self.missing_list.setText(targets_text(missing, where=False) if missing else "")
        if not missing:
            self.guidance.setText("")
        self._update()

    def show_guidance(self, text: str) -> None:
        """The way from the tip to the nearest missing node in the endoscope's view, or why none is given (the
        worker's words for the frame, :func:`snreg_gui.acquisition.hot_spots.guidance_text`)."""
        if self.missing:
            self.guidance.setText(text)

    def add_error_sources(self, node_id: str, sources: dict) -> None:
        """A stored node's covariance by source (the acquisition worker's ``node_error_sources``)."""
        self.error_sources[node_id] = sources
        self._update()

    def set_node_ids(self, ids: list[str]) -> None:
        """The stored nodes now (after a store, an undo, or a continued session): the advice covers these; an undone
        node's sources are forgotten."""
        for gone in set(self._node_ids) - set(ids):
            self.error_sources.pop(gone, None)
        self._node_ids = list(ids)
        self._update()

    def _update(self) -> None:
        """The advice from the stored nodes whose covariance by source is known (nodes stored before the app started
        have only their whole covariance), and each line shown while it has anything to say."""
        known = [i for i in self._node_ids if i in self.error_sources]
        of = ("the stored nodes' error variance" if len(known) == len(self._node_ids) else
              f"the error variance of {', '.join(known)} (stored since the app started)")
        self.advice.setText(advice_text([self.error_sources[i] for i in known], of))
        for line in (self.missing_list, self.guidance):
            line.setVisible(bool(self.missing))
        self.advice.setVisible(bool(self.advice.text()))
        self.setVisible(bool(self.missing or self.advice.text()))
