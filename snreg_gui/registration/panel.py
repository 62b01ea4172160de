"""The registration panel: preop nodes (file or SPECT), intraop nodes, method, initial alignment, run, view, export.

Why: after the intraop nodes are stored (trocar frame), the technician matches them to the preop SPECT nodes
and must see whether each pairing can be trusted before telling the surgeon. The panel only orchestrates:
:func:`snreg.registration.register` does the work in a worker thread, :mod:`snreg.registration.report`
makes the exports. With a writable session the preop set and each result are stored in it; with a session
opened for reading (review) the stored preop set and latest registration are shown and nothing is written.

The search starts from gravity by default (:mod:`snreg_gui.registration.start`: the SPECT's patient position and the
table's tilt, the IMU through the session's chain), or from the typed initial alignment when the operator touches it or
gravity is unknown (said in one sentence); that alignment puts the preop centroid on the intraop centroid, turns the
set about it and shifts it (:mod:`snreg_gui.registration.alignment`); the view shows the preop nodes under that
alignment until a result exists, then under the result's ``intraop_from_preop``, each node with its 90 % error
ellipsoid. Runs (Run, the automatic run after each store, exclusions) are :mod:`snreg_gui.registration.runs`. A preop
set loaded into a writable session is saved in it at once (in a worker), with its landmarks and its down, so the
session holds what the technician loaded. Anatomical landmarks (read with the preop nodes, stored in surgery) are
listed apart from the hot spots, drawn in the view and given to each run (:mod:`snreg_gui.registration.landmarks`).

>>> panel = RegistrationPanel()
>>> panel.set_session(session)                 # intraop (and stored preop) nodes from the session
>>> panel.load_preop("spect_folder")           # or a .csv / .mrk.json node file
>>> panel.registered.connect(on_result)        # RegistrationResult; also panel.last_result
>>> panel.run()
>>> acquisition_worker.node_stored.connect(panel.refresh_intraop)   # new nodes in the session
>>> panel.shutdown()                           # when the window closes
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (QCheckBox, QComboBox, QDoubleSpinBox, QFormLayout, QGroupBox, QHBoxLayout,
                               QLabel, QMessageBox, QProgressBar, QProgressDialog, QPushButton, QScrollArea, QSplitter,
                               QVBoxLayout, QWidget)

from snreg.nodes import NodeSet, read_node_file
from snreg.registration import METHOD_HELP, METHODS
from snreg.registration.naming import marked_missing, marked_rows, pairs_line
from snreg.registration.report import (mapped_preop, missing_nodes, node_warnings, pair_expected_mm, pair_rows,
                                       summary_line)
from snreg.workflow.chain_change import mixed_calibration_note
from snreg.workflow.guidance import targets_text
from snreg.workflow.navigation import NavigationState
from snreg.workflow.registration_run import EXPORTS, RunRecord
from snreg_gui.common import file_places
from snreg_gui.common.node_views import PREOP_OUT_OF_DATE, NodeScene, make_node_view
from snreg_gui.common.splitters import first_width
from snreg_gui.common.workers import WorkerSet, sentence
from snreg_gui.registration.alignment import AlignmentBox
from snreg_gui.registration.exports import PanelExports
from snreg_gui.registration.landmarks import LandmarkTable, PanelLandmarks
from snreg_gui.registration.navigation import PanelNavigation
from snreg_gui.registration.node_sets import count_text, has_nodes, made_from, without
from snreg_gui.registration.preop import PreopSourceBox
from snreg_gui.registration.runs import PanelRuns
from snreg_gui.registration.start import PanelStart, StartBox
from snreg_gui.registration.stored import StoredList
from snreg_gui.registration.tables import NodeTable, PairingTable, two_line_headers

DEFAULT_METHOD = "global"
VIEW_SHARE = 0.55           # of the results column's height, for the node view when the panel first shows


def _shown_rows(record: RunRecord) -> list:
    """The record's pairing rows as the panel shows them: preop ids marked "P:" when they repeat intraop ids."""
    return marked_rows(pair_rows(record.preop, record.intraop, record.result), record.preop.ids)


class RegistrationPanel(PanelRuns, PanelStart, PanelExports, PanelLandmarks, PanelNavigation, QWidget):
    """Emits ``registered(RegistrationResult)`` after each successful run; ``last_result`` holds the latest shown."""

    registered = Signal(object)
    missing_changed = Signal(list)     # MissingNode per preop node left unpaired by the result shown ([] without one)
    navigation_changed = Signal(object)   # NavigationState: what the feeds draw of the result shown, and if it is current

    def __init__(self, parent=None):
        super().__init__(parent)
        self.last_result = None
        self.missing_nodes: list = []              # MissingNode of the result shown
        self.navigation = NavigationState()        # ... with the hot spots found, its confidence and its currency
        self._session = None
        self._intraop: NodeSet | None = None
        self._intraop_from_session = False          # the intraop nodes are the session's (its chain gives their down)
        self._saving_preop = self._save_again = False
        self._record: RunRecord | None = None       # the result shown, with its node sets
        self._record_current = False                 # do the inputs still match it?
        self._registering = False
        self._rerun_pending = False                 # Run pressed during a run: run again when it ends
        self._auto_pending = False                  # a node stored during a run: register again when it ends
        self._excluded: set[str] = set()             # intraop ids left out of the next runs
        self._exporting = 0
        self.export_progress: QProgressDialog | None = None    # shown while an export is written
        self.export_problem: QMessageBox | None = None         # an export that failed, said in a box
        self._tasks = WorkerSet()
        self.preop_box = PreopSourceBox()
        self.intraop_source = QLabel("no intraop nodes: open a session or a node file")
        self.intraop_source.setWordWrap(True)
        self.intraop_open_button = QPushButton("Node file...")
        self.intraop_table = NodeTable()
        self.method_combo = QComboBox()
        for k, method in enumerate([DEFAULT_METHOD] + [m for m in METHODS if m != DEFAULT_METHOD]):
            self.method_combo.addItem(method)
            self.method_combo.setItemData(k, METHOD_HELP[method], Qt.ItemDataRole.ToolTipRole)
        self.method_combo.setToolTip(METHOD_HELP[DEFAULT_METHOD])        # the chosen method's, also when closed
        self.method_combo.currentTextChanged.connect(lambda m: self.method_combo.setToolTip(METHOD_HELP[m]))
        self.labels_check = QCheckBox("use labels (left/right, station)")
        self.rotation_bound = self._bound_spin(1.0, 180.0, 60.0, " deg")
        self.translation_bound = self._bound_spin(1.0, 500.0, 60.0, " mm")
        self.start_box = StartBox()                  # gravity or the typed alignment, and the table's tilt
        self.alignment = AlignmentBox()
        self.run_button = QPushButton("Run registration")
        self.busy_bar = QProgressBar()
        self.busy_bar.setRange(0, 0)
        self.busy_bar.setVisible(False)
        self.message = QLabel("")
        self.message.setWordWrap(True)
        self.view = make_node_view()
        self.summary = QLabel("no registration yet")
        self.summary.setWordWrap(True)
        self.pairing_table = PairingTable()
        self.landmark_table = LandmarkTable()         # apart from the hot spots; hidden without landmarks
        self.missing_label = QLabel("")
        self.missing_label.setWordWrap(True)
        self.exclude_button = QPushButton("Exclude selected and re-run")
        self.exclude_button.setToolTip("leave the selected intraop nodes out of the registration (e.g. one whose "
                                       "leave-one-out distance is large) and run it again")
        self.include_button = QPushButton("Include all")
        self.include_button.setEnabled(False)
        self.auto_rerun = QCheckBox("register again after each stored node")
        self.auto_rerun.setChecked(True)
        self.export_buttons = {kind: QPushButton(f"Export {name}...") for kind, (name, _, _) in EXPORTS.items()}
        self.stored = StoredList()
        self.final_label = QLabel("")               # which registration the exports write
        self.final_label.setWordWrap(True)
        self._layout()
        self._set_exports_enabled(False)
        self.preop_box.nodes_changed.connect(self._preop_changed)
        self.preop_box.landmarks_changed.connect(self._preop_landmarks_changed)
        self.intraop_open_button.clicked.connect(self._choose_intraop_file)
        self.alignment.changed.connect(self._inputs_changed)
        self.alignment.edited.connect(self.start_box.use_typed)       # typed angles override gravity
        self.start_box.changed.connect(self._start_changed)
        self.method_combo.currentTextChanged.connect(self._inputs_changed)
        self.labels_check.toggled.connect(self._inputs_changed)
        self.rotation_bound.valueChanged.connect(self._inputs_changed)
        self.translation_bound.valueChanged.connect(self._inputs_changed)
        self.run_button.clicked.connect(self.run)
        self.exclude_button.clicked.connect(self._exclude_selected)
        self.stored.final_requested.connect(self._mark_final)
        self.include_button.clicked.connect(self._include_all)
        for kind, button in self.export_buttons.items():
            button.clicked.connect(lambda _=False, k=kind: self._choose_export(k))
        self._show_start()

    @staticmethod
    def _bound_spin(low: float, high: float, value: float, suffix: str) -> QDoubleSpinBox:
        spin = QDoubleSpinBox()
        spin.setRange(low, high)
        spin.setValue(value)
        spin.setSuffix(suffix)
        return spin

    def _layout(self) -> None:
        intraop = QGroupBox("Intraop nodes (trocar frame)")
        intraop_layout = QVBoxLayout(intraop)
        row = QHBoxLayout()
        row.addWidget(self.intraop_source, 1)
        row.addWidget(self.intraop_open_button)
        intraop_layout.addLayout(row)
        intraop_layout.addWidget(self.intraop_table)
        settings = QGroupBox("Registration")
        form = QFormLayout(settings)
        form.addRow("method", self.method_combo)
        form.addRow(self.labels_check)
        form.addRow("max rotation", self.rotation_bound)
        form.addRow("max translation", self.translation_bound)
        form.addRow(self.auto_rerun)
        controls = QWidget()
        column = QVBoxLayout(controls)
        for widget in (self.preop_box, intraop, settings, self.start_box, self.alignment, self.stored):
            column.addWidget(widget)
        column.addStretch(1)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setWidget(controls)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)   # sideways it cut "SPEC"
        scroll.setMinimumWidth(controls.minimumSizeHint().width() + scroll.verticalScrollBar().sizeHint().width())
        left = QWidget()
        left_layout = QVBoxLayout(left)                  # Run stays visible below the scrolling settings
        left_layout.setContentsMargins(0, 0, 0, 0)
        left_layout.addWidget(scroll, 1)
        for widget in (self.start_box.status, self.run_button, self.busy_bar, self.message):
            left_layout.addWidget(widget)
        results = QWidget()
        results_layout = QVBoxLayout(results)
        results_layout.addWidget(self.summary)
        two_line_headers(self.pairing_table)
        results_layout.addWidget(self.pairing_table)
        results_layout.addWidget(self.landmark_table)
        exclusion = QHBoxLayout()
        exclusion.addWidget(self.exclude_button)
        exclusion.addWidget(self.include_button)
        exclusion.addStretch(1)
        results_layout.addLayout(exclusion)
        results_layout.addWidget(self.missing_label)
        results_layout.addWidget(self.final_label)
        exports = QHBoxLayout()
        for button in self.export_buttons.values():
            exports.addWidget(button)
        results_layout.addLayout(exports)
        right = self.view_splitter = QSplitter(Qt.Orientation.Vertical)
        right.addWidget(self.view)
        results_scroll = QScrollArea()              # warnings and the landmark table scroll, never clipped
        results_scroll.setWidgetResizable(True)
        results_scroll.setFrameShape(QScrollArea.Shape.NoFrame)
        results_scroll.setWidget(results)
        right.addWidget(results_scroll)
        right.setChildrenCollapsible(False)
        self.view.setMinimumHeight(250)            # a GL view hints no size: without this the splitter hides it
        right.setStretchFactor(0, 3)
        right.setStretchFactor(1, 2)
        self._view_sized = False
        main = QSplitter(Qt.Orientation.Horizontal)
        main.addWidget(left)
        main.addWidget(right)
        main.setChildrenCollapsible(False)
        main.setStretchFactor(1, 2)
        first_width(main, 0, lambda _: controls.sizeHint().width() + scroll.verticalScrollBar().sizeHint().width() + 4)
        layout = QVBoxLayout(self)
        layout.addWidget(main)

    def showEvent(self, event) -> None:
        """The first time the panel is shown, the node view gets :data:`VIEW_SHARE` of the splitter's height (the
        user moves the handle after that)."""
        super().showEvent(event)
        if not self._view_sized and self.view_splitter.height() > 0:
            self._view_sized = True
            height = self.view_splitter.height()
            self.view_splitter.setSizes([round(VIEW_SHARE * height), height - round(VIEW_SHARE * height)])

    # -- public API ------------------------------------------------------------
    @property
    def busy(self) -> bool:
        """True while a registration, export, preop read, segmentation or save of the preop set is under way."""
        return self._registering or self._exporting > 0 or self.preop_box.busy or self._saving_preop

    def set_session(self, session) -> None:
        """Intraop nodes, and the stored preop set and latest registration if any, from ``session``; None clears."""
        self._session = self.preop_box.session = session
        if session is None:
            self.set_intraop_landmarks(None)
            self._intraop_from_session = False
            self._set_intraop(None, "no intraop nodes: open a session or a node file")
            self._show_record(None)
            self.refresh_stored()
            return
        preop = session.preop_nodes()
        if preop is not None:
            self.preop_box.set_nodes(preop, f"session {session.case_id}", session.preop_landmarks(),
                                     session.preop_down())
        self.refresh_intraop()
        stored = session.registrations()
        latest = stored[-1] if stored else None
        if latest is not None and preop is not None and made_from(latest, preop, self._intraop):
            self._show_record(RunRecord(preop, self._intraop, latest.result,
                                        f"Registration {latest.n} from the session.",
                                        preop_landmarks=self.preop_box.landmarks,
                                        intraop_landmarks=self._intraop_landmarks))
        self.refresh_stored()

    def refresh_intraop(self, *_) -> None:
        """Re-read the intraop nodes from the session (connect to "node stored"); no-op without a session."""
        if self._session is not None:
            nodes = self._session.intraop_nodes()
            self._intraop_from_session = True
            mixed = mixed_calibration_note(self._session.intraop_records())
            self.set_intraop_landmarks(self._session.intraop_landmarks())
            marks = len(self._intraop_landmarks or ())
            and_marks = f" and {marks} landmark{'s' * (marks != 1)}" if marks else ""
            self._set_intraop(nodes, f"{count_text(nodes)}{and_marks} from session {self._session.case_id}"
                                     + (" - MAPPED WITH MIXED CALIBRATIONS" if mixed else ""))
            self.intraop_source.setToolTip(mixed)

    def set_intraop_nodes(self, nodes: NodeSet) -> None:
        """Use these intraop nodes (trocar frame, mm); a node file carries no down, so no start from gravity."""
        self._intraop_from_session = False
        self._set_intraop(nodes, count_text(nodes) + (f" ({nodes.frame} frame)" if nodes.frame else ""))

    def load_preop(self, path) -> None:
        """Read preop nodes from a node file (.csv, .mrk.json) or a SPECT DICOM file or folder, in a worker."""
        self.preop_box.load(path)

    def shutdown(self) -> None:
        """Wait for every worker of the panel (call when the window closes)."""
        self.preop_box.shutdown()
        self._tasks.shutdown()

    # -- inputs ------------------------------------------------------------------
    def _say(self, text: str) -> None:
        self.message.setText(text)

    def _say_problem(self, message: str) -> None:
        self._say(sentence(message))

    def _set_intraop(self, nodes: NodeSet | None, source: str) -> None:
        self._intraop = nodes
        self.intraop_source.setText(source)
        self.intraop_table.show_nodes(nodes)
        self._inputs_changed()

    def _preop_changed(self, nodes: NodeSet | None) -> None:
        """New preop nodes: saved with their down in a writable session at once (a worker; nothing is written when the
        session holds them already, e.g. its own set shown again), and the result shown no longer answers the inputs.
        A tilt that came entered with them is shown."""
        self.start_box.take_tilt(self.preop_box.down)
        self._save_preop(nodes)
        self._inputs_changed()

    def _choose_intraop_file(self) -> None:
        path = file_places.choose_file(self, "Intraop node file", self._session, "Node files (*.csv *.mrk.json *.json)")
        if path:
            self._tasks.start(read_node_file, path, returned=self._intraop_file_read, errored=self._say_problem)

    def _inputs_changed(self, *_) -> None:
        """Preop, intraop, alignment, method, labels or bounds changed: the result shown no longer answers them, so
        its pairing table is greyed, the exports are disabled and the view shows the initial alignment until the
        next run (a re-segmented SPECT renumbers the preop ids: the old table must not pass for current)."""
        self._record_current = False
        record = self._record
        if record is not None:
            self.summary.setText(f"OUT OF DATE, inputs changed since: run again "
                                 f"(was {summary_line(record.result, _shown_rows(record))})")
        self.pairing_table.setEnabled(False)
        self._update_exports()
        self._show_start()
        self._guidance_out_of_date()
        self._refresh_view()

    def _refresh_view(self) -> None:
        record = self._record
        if record is not None and self._record_current:
            scene = NodeScene(mapped_preop(record.preop, record.result), record.intraop, record.result.pairing,
                              record.result.missing, **self._landmark_scene(record, record.result.transform))
        else:
            preop, intraop = self.preop_box.nodes, self._intraop
            kept = without(intraop, self._excluded) if has_nodes(intraop) else None
            initial = (self.alignment.transform(preop.xyz, None if kept is None else kept.xyz) if has_nodes(preop)
                       else None)
            moved = preop.moved(initial) if has_nodes(preop) else None
            scene = NodeScene(moved, intraop, preop_caption=PREOP_OUT_OF_DATE if record is not None else None,
                              **self._landmark_scene(None, np.eye(4) if initial is None else initial))
        self.view.show_scene(scene)

    # -- results -----------------------------------------------------------------
    @property
    def current_result(self):
        """The result shown while it answers the inputs (the nodes stored now, the preop set, ...); None otherwise."""
        return self.last_result if self._record_current else None

    def pairs_line(self) -> str:
        """The result shown, one line: which hot spot each intraop node came from ("" without a result)."""
        record = self._record
        return "" if record is None else pairs_line(record.preop, record.intraop, record.result)

    def _show_record(self, record: RunRecord | None, current: bool = True) -> None:
        """Show ``record`` (None: none); one that no longer answers the inputs (``current`` False: a node stored while
        it ran) is shown out of date and names no SPECT node missing."""
        self._record, self._record_current = record, record is not None
        self.last_result = None if record is None else record.result
        rows = [] if record is None else _shown_rows(record)
        self.pairing_table.show_rows(rows, [] if record is None else pair_expected_mm(record.intraop, record.result))
        self.pairing_table.setEnabled(record is not None)
        self.summary.setText("no registration yet" if record is None else "\n".join(
            [summary_line(record.result, rows)] + [record.start] * bool(record.start)
            + [record.used[:1].upper() + record.used[1:]] * bool(record.used)
            + [record.weighing] * bool(record.weighing)
            + [f"WARNING: {text}" for text in node_warnings(rows)]))
        self._landmark_summary(record)
        missing = [] if record is None or not current else marked_missing(
            missing_nodes(record.preop, record.result), record.intraop.ids, record.preop.ids)
        self.missing_label.setText("Not found yet (trocar frame):\n" + targets_text(missing) if missing else "")
        self.missing_nodes = missing
        self.missing_changed.emit(missing)
        self._set_navigation(self._navigation_of(record, missing, current))
        self._say("" if record is None else record.note)
        if not current:
            self._inputs_changed()
        self._update_exports()
        self._refresh_view()
