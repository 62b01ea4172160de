"""The preop box's report of stations: "Stations..." labels a SPECT's hot spots with the stations its report names.

Why: a nuclear-medicine report names each sentinel node's station on the SPECT/CT (thesis Table 1). With it the hot
spots are labelled "EXT L" instead of "L", so the labels the technician types pair on station as well as side, as
``snreg preop SPECT --stations CSV`` does (:func:`snreg.preop.segment.read_station_table`, CSV ``id,station``). The
table is read and the SPECT re-segmented with it in one worker; the stations then stay for every re-segmentation of
the same SPECT (threshold slider, node count) and go when another SPECT or a node file is loaded, since their ids
(``P1``...) name that SPECT's hot spots. An unreadable table, or one naming a hot spot the segmentation does not have,
is said in one sentence and changes nothing. A mixin of :class:`~snreg_gui.registration.preop.PreopSourceBox`.
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtWidgets import QPushButton

from snreg_gui.common import file_places
from snreg_gui.common.workers import sentence
from snreg_gui.registration.preop_read import read_stations

STATION_FILTER = "Station tables (*.csv *.txt);;All files (*)"


class BoxStations:
    """The box's stations (module docstring): ``stations`` (hot spot id -> station; None: sides only) and the table's
    name (``stations_source``); both are those of the nodes shown."""

    stations: dict[str, str] | None = None
    stations_source = ""
    _station_reads = 0              # station tables being read (and the SPECT re-segmented with them)

    def _stations_button(self) -> QPushButton:
        self.stations_button = QPushButton("Stations...")
        self.stations_button.setToolTip("read the SPECT report's stations (CSV id,station, e.g. P1,EXT): the hot "
                                        "spots are labelled 'EXT L' instead of 'L' and pair on station as well")
        self.stations_button.clicked.connect(self._choose_station_table)
        return self.stations_button

    # -- public --------------------------------------------------------------
    def load_stations(self, path) -> None:
        """Read a station table in a worker and re-segment the loaded SPECT with it; a failure changes nothing."""
        if self._loading:
            self.status.setText("Wait until the file being read is shown, then read the stations of its SPECT.")
            return
        if self._volume is None:
            self.status.setText("Load a SPECT first: a station table names the hot spots of a SPECT.")
            return
        self._generation += 1           # a re-segmentation under way or due is for the old stations: run again after
        self._pending = self._pending or self._segmenting or self._timer.isActive()
        self._timer.stop()
        self._station_reads += 1
        self.status.setText(f"reading stations from {Path(path).name}...")
        self._tasks.start(read_stations, self._generation, str(path), self._volume, self.threshold, self.n_nodes,
                          self._source, returned=self._stations_read, errored=self._stations_failed)

    # -- internals -----------------------------------------------------------
    def _choose_station_table(self) -> None:
        path = file_places.choose_file(self, "SPECT report: station table", self.session, STATION_FILTER)
        if path:
            self.load_stations(path)

    @property
    def stations_reading(self) -> bool:
        """A station table is being read and the SPECT re-segmented with it."""
        return self._station_reads > 0

    def _stations_read(self, read) -> None:
        self._station_reads -= 1
        if read.generation == self._generation:
            self._show_read(read)
        self._run_pending()

    def _stations_failed(self, message: str) -> None:
        self._station_reads -= 1
        self.status.setText(sentence(message))
        self._run_pending()

    def _run_pending(self) -> None:
        if self._pending:
            self._pending = False
            self._resegment()

    def _stations_text(self) -> str:
        """", stations from X" for nodes labelled with a station table, else ""."""
        return f", stations from {self.stations_source}" if self.stations is not None else ""
