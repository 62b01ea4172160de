"""The registration panel's runs: Run, the automatic run after each stored node, and leaving nodes out.

Why apart: :class:`~snreg_gui.registration.panel.RegistrationPanel` lays out the inputs and shows a result; this part
decides when a registration runs and with what (:class:`~snreg.workflow.registration_run.RunRequest`), runs it in a
worker and hands the outcome back. The automatic run after a store is what keeps "if registered now" true on the
acquisition screen: the SPECT nodes not found yet and their expected errors (``missing_changed``). A mixin of the
panel, using its widgets (``run_button``, ``busy_bar``, ``auto_rerun``, ``alignment``, ``method_combo``, bounds,
the start (``_start_choice``: gravity or the typed alignment, and why),
``pairing_table``, ``include_button``) and state (``_session``, ``_intraop``, ``_excluded``, ``_registering``,
``_rerun_pending``, ``_auto_pending``, ``_tasks``); the feeds hear of each run through
:mod:`~snreg_gui.registration.navigation` (``_navigation_stale``, ``_run_coming``: "updating" while a run will answer).
"""

from __future__ import annotations

from snreg.workflow.registration_run import RunRecord, RunRequest
from snreg_gui.registration.landmarks import needed_nodes
from snreg_gui.registration.node_sets import has_nodes, same_nodes, without
from snreg_gui.registration.start import run_from

MIN_PAIRS = 3       # points a registration needs: nodes, and landmark pairs making up the 3 with 1 node at least (§4)
POINTS = "3 points (nodes, and landmarks named on both sides; 1 node at least)"


def too_few_text(kept: int, left_out: list[str], pairs: int = 0) -> str:
    """Why a registration of ``kept`` intraop nodes (beside ``pairs`` landmark pairs) cannot run, and what to do:
    store more, or (when ``left_out`` ids were excluded) include some; "" when there are enough."""
    needed = needed_nodes(pairs)
    if kept >= needed:
        return ""
    nodes = f"{kept} intraop node{'s' * (kept != 1)}"
    if pairs:
        beside = f"{nodes} beside {pairs} landmark pair{'s' * (pairs != 1)}"
        if left_out:
            return (f"Only {beside} once {', '.join(left_out)} {'is' if len(left_out) == 1 else 'are'} left out; "
                    f"registration needs {POINTS}: include some (Include all) or store more.")
        return f"Only {beside} so far; registration needs {POINTS}: store {needed - kept} more node or landmark."
    if not left_out:
        return (f"Only {nodes} so far; registration needs at least {MIN_PAIRS}: store {MIN_PAIRS - kept} more "
                "(or open a node file with more).")
    return (f"Only {nodes} left once {', '.join(left_out)} {'is' if len(left_out) == 1 else 'are'} left out; "
            f"registration needs at least {MIN_PAIRS}: include some (Include all) or store more.")


class PanelRuns:
    """When and with what the registration panel registers (module docstring)."""

    def run(self) -> None:
        """Register the current preop to the current intraop nodes with the chosen settings, in a worker; the result
        is stored in a writable session."""
        self._start(automatic=False)

    def rerun_after_store(self) -> None:
        """A node was stored: re-read the session's nodes and, when "register again" is ticked and both node sets
        are there and no run is under way, register again (not stored in the session: Run stores the one that
        counts)."""
        self._run_coming = self.auto_rerun.isChecked()      # the feeds say "updating" meanwhile, not "out of date"
        try:
            self.refresh_intraop()
            if not (self.auto_rerun.isChecked() and has_nodes(self.preop_box.nodes) and self._intraop is not None
                    and len(self._intraop) >= needed_nodes(len(self.landmark_pairs()))):
                return
            if self._registering:
                self._auto_pending = True
            else:
                self._start(automatic=True)
        finally:
            self._run_coming = False
            self._navigation_stale()                        # out of date when no run follows (too few nodes left)

    def _start(self, automatic: bool) -> None:
        """Start a run; an automatic one (after a store) is not stored in the session and leaves Run enabled."""
        preop, intraop = self.preop_box.nodes, self._intraop
        if self._registering:                       # the latest inputs run as soon as the current run ends
            self._rerun_pending = self._rerun_pending or not automatic
            return self._say("A registration is running; it will run again with these settings when it ends.")
        if not has_nodes(preop):
            return self._say("Load the preop nodes first: a node file or a SPECT.")
        if not has_nodes(intraop):
            return self._say("There are no intraop nodes yet: store nodes or open an intraop node file.")
        pairs = len(self.landmark_pairs())
        if len(preop) < needed_nodes(pairs):
            with_pairs = f" points with {pairs} landmark pair{'s' * (pairs != 1)}" if pairs else ""
            return self._say(f"Only {len(preop)} preop node{'s' * (len(preop) != 1)}; registration needs at least "
                             f"{MIN_PAIRS}{with_pairs}: lower the SPECT threshold or open another node file.")
        kept = without(intraop, self._excluded)
        problem = too_few_text(len(kept), [i for i in intraop.ids if i in self._excluded], pairs)
        if problem:
            return self._say(problem)
        store = not automatic and self._session is not None and same_nodes(
            kept, without(self._session.intraop_nodes(), self._excluded))
        start = self._start_choice()
        request = RunRequest(preop, kept, self.method_combo.currentText(), self.labels_check.isChecked(),
                             self.alignment.transform(preop.xyz, kept.xyz), self.rotation_bound.value(),
                             self.translation_bound.value(), self._session if store else None,
                             gravity=start.gravity, preop_down=self._preop_down())
        request = self._with_landmarks(request)
        self._registering = True
        self._navigation_stale()                    # the feeds say "updating" until it ends
        self.run_button.setEnabled(automatic)
        self.busy_bar.setVisible(True)
        left_out = f", without {', '.join(sorted(self._excluded))}" if self._excluded else ""
        self._say(f"Registering {len(preop)} preop to {len(kept)} intraop nodes ({request.method}{left_out})...")
        self._tasks.start(run_from, request, start.words,
                          returned=self._registration_done, errored=self._registration_failed)

    def _registration_done(self, record: RunRecord) -> None:
        """Show the result; when its node sets are no longer the inputs (a node stored or undone, the preop set
        changed while it ran) it is shown out of date, so no SPECT node is said missing that was just found."""
        current = record.preop is self.preop_box.nodes and has_nodes(self._intraop) and same_nodes(
            record.intraop, without(self._intraop, self._excluded))
        self._registration_ended()
        self._show_record(record, current)
        if record.stored:
            self.refresh_stored()
        if self._excluded:
            self._say(f"{record.note} Left out of this registration: {', '.join(sorted(self._excluded))}.".strip())
        self.registered.emit(record.result)

    def _registration_failed(self, message: str) -> None:
        self._registration_ended()
        self._navigation_stale()                    # out of date unless another run started
        self._say_problem(message)

    def _registration_ended(self) -> None:
        self._registering = False
        self.run_button.setEnabled(True)
        self.busy_bar.setVisible(False)
        if self._rerun_pending or self._auto_pending:
            automatic = not self._rerun_pending
            self._rerun_pending = self._auto_pending = False
            self._start(automatic=automatic)

    def _exclude_selected(self) -> None:
        chosen = self.pairing_table.selected_intraop_ids()
        if not chosen:
            return self._say("Select the intraop node(s) to leave out in the pairing table first.")
        self._excluded |= set(chosen)
        self.include_button.setEnabled(True)
        self.run()

    def _include_all(self) -> None:
        self._excluded.clear()
        self.include_button.setEnabled(False)
        self.run()
