"""Where the registration panel gets its preop nodes: a node file, or a SPECT DICOM segmented live.

Why: the threshold that separates sentinel nodes from higher echelons is a judgement (thesis §3.3), so the
technician moves a slider and sees how many nodes it gives. The volume is read once; each slider or
node-count change re-segments it in a worker after a short pause (debounce), and a result made for an older
file or older settings is dropped. Same threshold meaning as ``snreg preop --threshold`` (fraction of the
maximum activity). A node file's landmarks (a CSV's rows of ``kind`` landmark, a markups file's landmark points) come
in apart, as ``box.landmarks`` (ids = names; none from a SPECT): they are never hot spots. "Landmarks..." reads them
from a file of their own, "clear" forgets them (:mod:`snreg_gui.registration.preop_marks`: which source replaces which).

>>> box = PreopSourceBox()
>>> box.nodes_changed.connect(panel_slot)      # NodeSet, LPS mm for a SPECT
>>> box.load("spect_folder")                   # or a .csv / .mrk.json node file
>>> box.load_landmarks("ct_landmarks.mrk.json")  # RAS or LPS; box.landmarks in LPS, landmarks_changed emitted
>>> box.load_stations("report_stations.csv")    # a SPECT's hot spots labelled "EXT L"... (preop_stations)
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import QFileDialog, QFormLayout, QGroupBox, QHBoxLayout, QLabel, QPushButton, QSlider, QSpinBox

from snreg.nodes import NodeSet
from snreg.preop import Volume
from snreg.preop.gravity import PreopDown
from snreg_gui.common import file_places
from snreg_gui.common.workers import WorkerSet, sentence
from snreg_gui.registration.preop_marks import BoxLandmarks, plural
from snreg_gui.registration.preop_read import PreopRead, read_preop, segment
from snreg_gui.registration.preop_stations import BoxStations
from snreg_gui.registration.tables import NodeTable

DEFAULT_THRESHOLD_PERCENT = 30          # snreg preop's default, 0.3 x maximum
RESEGMENT_DELAY_MS = 250


class PreopSourceBox(BoxStations, BoxLandmarks, QGroupBox):
    """Open buttons, threshold slider, node-count box, status line and the table of preop nodes.

    Emits ``nodes_changed(NodeSet)`` whenever the preop nodes change (file read, re-segmented, or
    :meth:`set_nodes`); ``down`` is then what gives their down as read (:class:`PreopDown`, None when the source
    records none). ``status`` says how many nodes were found, or what went wrong, in one sentence. Emits
    ``landmarks_changed(NodeSet or None)`` when a landmark file is read or the landmarks cleared (with nodes, the
    landmarks read with them come with ``nodes_changed``). A SPECT's hot spots carry the stations of its report once
    one is read (:meth:`load_stations`, "Stations...": :mod:`snreg_gui.registration.preop_stations`).
    """

    nodes_changed = Signal(object)
    landmarks_changed = Signal(object)

    def __init__(self, parent=None):
        super().__init__("Preop nodes (SPECT)", parent)
        self.nodes: NodeSet | None = None
        self.landmarks: NodeSet | None = None     # ids = names, LPS mm; None: none (BoxLandmarks)
        self.down: PreopDown | None = None
        self.session = None                  # the panel's session: its folder is where the file dialogs start
        self._volume: Volume | None = None
        self._source = ""
        self._generation = 0
        self._loading = self._segmenting = self._pending = False
        self._tasks = WorkerSet()
        self.open_file_button = QPushButton("Node file...")
        self.open_spect_button = QPushButton("SPECT file...")
        self.open_folder_button = QPushButton("SPECT folder...")
        self.threshold_slider = QSlider(Qt.Orientation.Horizontal)
        self.threshold_slider.setRange(1, 99)
        self.threshold_slider.setValue(DEFAULT_THRESHOLD_PERCENT)
        self.threshold_slider.setToolTip("activity threshold as a fraction of the volume's maximum")
        self.threshold_label = QLabel()
        self.count_spin = QSpinBox()
        self.count_spin.setRange(0, 50)
        self.count_spin.setSpecialValueText("auto")
        self.count_spin.setToolTip("expected number of nodes (auto: as many as the threshold gives)")
        self.status = QLabel("no preop nodes: open a node file or a SPECT")
        self.status.setWordWrap(True)
        self.table = NodeTable()
        self._timer = QTimer(self, singleShot=True, interval=RESEGMENT_DELAY_MS, timeout=self._resegment)
        self._layout()
        self._show_threshold()
        self._set_spect_controls(False)
        self.open_file_button.clicked.connect(self._choose_node_file)
        self.open_spect_button.clicked.connect(self._choose_spect_file)
        self.open_folder_button.clicked.connect(self._choose_spect_folder)
        self.threshold_slider.valueChanged.connect(self._settings_changed)
        self.count_spin.valueChanged.connect(self._settings_changed)

    def _layout(self) -> None:
        buttons = QHBoxLayout()
        for button in (self.open_file_button, self.open_spect_button, self.open_folder_button, self._stations_button()):
            buttons.addWidget(button)
        threshold = QHBoxLayout()
        threshold.addWidget(self.threshold_slider)
        threshold.addWidget(self.threshold_label)
        form = QFormLayout(self)
        form.addRow(buttons)
        form.addRow("landmarks", self._landmark_controls())
        form.addRow("threshold", threshold)
        form.addRow("nodes", self.count_spin)
        form.addRow(self.status)
        form.addRow(self.table)

    # -- public --------------------------------------------------------------
    @property
    def threshold(self) -> float:
        return self.threshold_slider.value() / 100.0

    @property
    def n_nodes(self) -> int | None:
        return self.count_spin.value() or None

    @property
    def busy(self) -> bool:
        return (self._loading or self._segmenting or self.stations_reading or self.marks_reading
                or self._timer.isActive())

    def load(self, path, stations=None) -> None:
        """Read a node file (.csv, .mrk.json) or a SPECT DICOM file or folder, in a worker; a SPECT's hot spots
        labelled with the station table at ``stations`` when given (the stations of an earlier SPECT never carry over)."""
        self._generation += 1
        self._loading, self._pending = True, False
        self._timer.stop()
        self.status.setText(f"reading {Path(path).name}...")
        self._tasks.start(read_preop, self._generation, str(path), self.threshold, self.n_nodes,
                          None if stations is None else str(stations), returned=self._read_done, errored=self._failed)

    def set_nodes(self, nodes: NodeSet | None, source: str, landmarks: NodeSet | None = None,
                  down: PreopDown | None = None) -> None:
        """Show nodes given directly (e.g. a session's stored preop set, with its ``landmarks`` and the down stored
        with them); no volume to re-segment."""
        self._generation += 1
        self._volume, self._loading, self._pending = None, False, False
        self._timer.stop()
        self._set_spect_controls(False)
        self.stations, self.stations_source = None, ""
        self._show(nodes, source, landmarks, down, replace_marks=True)

    def shutdown(self) -> None:
        self._timer.stop()
        self._tasks.shutdown()

    # -- internals -----------------------------------------------------------
    def _choose_node_file(self) -> None:
        path = file_places.choose_file(self, "Preop node file", self.session, "Node files (*.csv *.mrk.json *.json)")
        if path:
            self.load(path)

    def _choose_spect_file(self) -> None:
        path = file_places.choose_file(self, "SPECT DICOM file", self.session, "DICOM (*.dcm *.DCM *.ima);;All files (*)")
        if path:
            self.load(path)

    def _choose_spect_folder(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "SPECT DICOM series folder", file_places.start_path(self.session))
        if path:
            file_places.remember(path)
            self.load(path)

    def _settings_changed(self) -> None:
        self._show_threshold()
        if self._volume is not None:
            self._timer.start()

    def _show_threshold(self) -> None:
        self.threshold_label.setText(f"{self.threshold:.2f} x max")

    def _set_spect_controls(self, enabled: bool) -> None:
        self.threshold_slider.setEnabled(enabled)
        self.count_spin.setEnabled(enabled)
        self.stations_button.setEnabled(enabled)

    def _resegment(self) -> None:
        if self._volume is None:
            return
        if self._segmenting or self.stations_reading:
            self._pending = True
            return
        self._segmenting = True
        self.status.setText(f"segmenting at {self.threshold:.2f} x maximum...")
        self._tasks.start(segment, self._generation, self._volume, self.threshold, self.n_nodes, self._source,
                          self.stations, self.stations_source, returned=self._segment_done, errored=self._failed)

    def _read_done(self, read: PreopRead) -> None:
        if read.generation != self._generation:
            return
        self._loading = False
        self._volume = read.volume
        self._set_spect_controls(read.volume is not None)
        self._show_read(read)

    def _segment_done(self, read: PreopRead) -> None:
        self._segmenting = False
        if read.generation == self._generation:
            self._show_read(read)
        self._run_pending()

    def _failed(self, message: str) -> None:
        self._loading = self._segmenting = False
        self.status.setText(sentence(message))
        self._run_pending()

    def _show_read(self, read: PreopRead) -> None:
        """Show a worker's nodes with the stations they were labelled with."""
        self.stations, self.stations_source = read.stations, read.stations_source
        self._show(read.nodes, read.source, read.landmarks, read.down)

    def _show(self, nodes: NodeSet | None, source: str, landmarks: NodeSet | None = None,
              down: PreopDown | None = None, replace_marks: bool = False) -> None:
        """Show ``nodes`` from ``source``; ``landmarks`` read with them replace those shown, none keep them unless
        ``replace_marks`` (:meth:`set_nodes`)."""
        self.nodes, self._source, self.down = nodes, source, down
        self.table.show_nodes(nodes)
        self._take_landmarks(landmarks, source, replace_marks)
        self.nodes_changed.emit(nodes)

    def _show_status(self) -> None:
        """"4 nodes above 0.30 x maximum in X; 3 landmarks from Y", "4 nodes and 3 landmarks from Z", ..."""
        nodes, source = self.nodes, self._source
        count = plural(0 if nodes is None else len(nodes), "node")
        marks = self._landmark_text(source)
        if self._volume is not None:
            text = f"{count} above {self.threshold:.2f} x maximum in {source}{self._stations_text()}"
        elif nodes is None:
            text = "no preop nodes: open a node file or a SPECT"
        else:
            own = f" and {plural(len(self.landmarks), 'landmark')}" if self.landmarks is not None and not marks else ""
            text = f"{count}{own} from {source}"
        self.status.setText(text + marks + (f" (replacing the {self._replaced})" if self._replaced else ""))
