"""What the acquisition screen may show of the registration panel's result: the hot spots not found yet it lists
(``missing_changed``) and what the feeds draw: those hot spots, the ones found, the pairing's confidence, and whether
the result is current (:class:`~snreg.workflow.navigation.NavigationState`, sent as ``navigation_changed``).

Why apart: a result that no longer answers the inputs must never be drawn as current, and greyed targets must say the
true reason: "updating" only while a registration runs that will answer the nodes stored now; else "out of date" with
what to do (inputs changed by hand, a run that failed or was refused, a result that came back for nodes since
changed, nodes stored while "register again" is off). A mixin of :class:`~snreg_gui.registration.panel.
RegistrationPanel`, using its signals, ``navigation``, ``missing_nodes``, ``missing_label`` and ``_registering``.
"""

from __future__ import annotations

from dataclasses import replace

from snreg.workflow.navigation import UPDATING, NavigationState, navigation_state

OUT_OF_DATE = "out of date since nodes or settings changed: press Run registration"   # short: it lies over the feeds


class PanelNavigation:
    """The feeds' view of the result shown (module docstring)."""

    _run_coming = False          # a registration of the nodes stored now is about to start (after a store)

    def _set_navigation(self, state: NavigationState) -> None:
        self.navigation = state
        self.navigation_changed.emit(state)

    def _stale_reason(self) -> str:
        return UPDATING if self._registering or self._run_coming else OUT_OF_DATE

    def _navigation_of(self, record, missing: list, current: bool) -> NavigationState:
        """The state of ``record`` (None: none) with its ``missing`` targets; stale from the start when not
        ``current``."""
        if record is None:
            return NavigationState()
        state = replace(navigation_state(record.preop, record.result), targets=tuple(missing))
        return state if current else state.updating(self._stale_reason())

    def nodes_changed_unseen(self) -> None:
        """Nodes were stored or undone and the panel re-reads them only when next shown ("register again" off): the
        acquisition screen stops listing its result's hot spots and the feeds grey them, out of date, now."""
        self._guidance_out_of_date()

    def _guidance_out_of_date(self) -> None:
        """No list of hot spots from a result that no longer answers the inputs; its targets greyed on the feeds."""
        if self.missing_nodes:
            self.missing_nodes = []
            self.missing_label.setText("")
            self.missing_changed.emit([])
        self._navigation_stale()

    def _navigation_stale(self) -> None:
        """The feeds' hot spots are no longer current (or a run started or ended): greyed, "updating" while a run will
        answer the nodes stored now, else out of date until the technician registers again."""
        why = self._stale_reason()
        if (self.navigation.targets or self.navigation.found) and self.navigation.stale != why:
            self._set_navigation(self.navigation.updating(why))
