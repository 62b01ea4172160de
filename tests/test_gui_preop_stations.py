"""The preop box's "Stations...": a SPECT report's station table labels the hot spots (offscreen, real widgets)."""

import numpy as np
import pytest
from PySide6.QtCore import Qt

from snreg.demo.spect import spect_of_nodes, write_nm
from snreg.nodes import NodeSet, write_nodes
from snreg_gui.common import file_places

TIMEOUT_MS = 15_000
# two nodes 20 mm apart, the second at half the activity (gone above 0.6 x maximum), and a third far away
SOURCES = np.array([[-20.0, 50.0, 55.0], [0.0, 50.0, 55.0], [40.0, 60.0, 40.0]])
STATIONS = {"P1": "EXT", "P2": "OBT", "P3": "INT"}


@pytest.fixture
def spect(tmp_path):
    counts, origin = spect_of_nodes(SOURCES, activity=[1.0, 0.5, 1.0], shape=(40, 48, 48), seed=1)
    return write_nm(counts, origin, 4.795, tmp_path / "spect.dcm")[0]


def write_table(path, stations: dict) -> str:
    path.write_text("id,station\n" + "".join(f"{i},{s}\n" for i, s in stations.items()), encoding="utf-8")
    return str(path)


def loaded(qtbot, panel, path, **stations):
    box = panel.preop_box
    box.load(path, **stations)
    qtbot.waitUntil(lambda: not panel.busy and box.nodes is not None, timeout=TIMEOUT_MS)
    return box


def stations_of(nodes: NodeSet) -> list[str]:
    return [label.split()[0] for label in nodes.labels]


def labelled(box, sides: NodeSet) -> list[str]:
    """The labels the nodes of ``sides`` (read without stations) get with :data:`STATIONS`."""
    return [f"{STATIONS[i]} {side}" for i, side in zip(sides.ids, sides.labels)]


def test_stations_button_relabels_the_hot_spots_and_they_stay_for_the_slider(qtbot, panel, spect, tmp_path,
                                                                            monkeypatch):
    box = panel.preop_box
    assert not box.stations_button.isEnabled()                     # nothing to label yet
    loaded(qtbot, panel, spect)
    sides = box.nodes
    assert len(sides) == 3 and set(sides.labels) <= {"L", "R"} and box.stations_button.isEnabled()
    table = write_table(tmp_path / "report.csv", STATIONS)
    monkeypatch.setattr(file_places, "choose_file", lambda *a, **k: table)
    qtbot.mouseClick(box.stations_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not panel.busy and box.stations is not None, timeout=TIMEOUT_MS)
    assert box.nodes.labels == labelled(box, sides) and box.nodes.ids == sides.ids
    np.testing.assert_allclose(box.nodes.xyz, sides.xyz)
    assert box.status.text() == "3 nodes above 0.30 x maximum in spect.dcm, stations from report.csv"
    assert box.table.item(0, 1).text() == box.nodes.labels[0]
    box.threshold_slider.setValue(40)                              # still three hot spots: the stations stay
    qtbot.waitUntil(lambda: not panel.busy and "0.40" in box.status.text(), timeout=TIMEOUT_MS)
    assert stations_of(box.nodes) == [STATIONS[i] for i in box.nodes.ids]   # each id its station (ids may reorder)
    assert box.status.text().endswith(", stations from report.csv")


def test_a_threshold_that_loses_a_named_hot_spot_says_so_and_keeps_the_nodes(qtbot, panel, spect, tmp_path):
    box = loaded(qtbot, panel, spect, stations=write_table(tmp_path / "report.csv", STATIONS))
    shown = box.nodes
    assert box.stations == STATIONS and len(shown) == 3
    box.threshold_slider.setValue(60)                              # P3 gone: the table names a hot spot not found
    qtbot.waitUntil(lambda: not panel.busy and "P3" in box.status.text(), timeout=TIMEOUT_MS)
    text = box.status.text()
    assert text.startswith("The station table names P3, but the nodes found are P1 to P2") and text.endswith(".")
    assert box.nodes is shown and box.stations == STATIONS
    box.threshold_slider.setValue(30)                              # back: labelled with the same stations
    qtbot.waitUntil(lambda: not panel.busy and "0.30" in box.status.text(), timeout=TIMEOUT_MS)
    assert stations_of(box.nodes) == [STATIONS[i] for i in box.nodes.ids]


@pytest.mark.parametrize("content, said", [("id;station\nP1;EXT\n", "needs a header 'id,station'"),
                                           ("id,station\nP1,EXT\nP9,OBT\n", "names P9, but the nodes found are P1"),
                                           ("id,station\nP1,ABC\n", "'ABC' for P1 is not a known station")])
def test_a_bad_station_table_is_one_sentence_and_loses_nothing(qtbot, panel, spect, tmp_path, content, said):
    box = loaded(qtbot, panel, spect, stations=write_table(tmp_path / "good.csv", {"P1": "EXT"}))
    shown = box.nodes
    assert shown.labels[0].startswith("EXT ")
    path = tmp_path / "bad.csv"
    path.write_text(content, encoding="utf-8")
    box.load_stations(path)
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    text = box.status.text()
    assert said in text and text.endswith(".") and "\n" not in text
    assert box.nodes is shown and box.stations == {"P1": "EXT"} and box.stations_source == "good.csv"
    box.load_stations(tmp_path / "missing.csv")
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    assert "missing.csv" in box.status.text() and box.nodes is shown


def test_another_spect_or_a_node_file_drops_the_stations(qtbot, panel, spect, tmp_path):
    box = loaded(qtbot, panel, spect, stations=write_table(tmp_path / "report.csv", STATIONS))
    assert box.nodes.labels[0].startswith(STATIONS["P1"])
    loaded(qtbot, panel, spect)                                    # read again: its ids may now name other hot spots
    assert box.stations is None and set(box.nodes.labels) <= {"L", "R"} and "stations" not in box.status.text()
    write_nodes(NodeSet.from_xyz(SOURCES, ["EXT L", "OBT R", "INT L"]), tmp_path / "nodes.csv")
    loaded(qtbot, panel, str(tmp_path / "nodes.csv"))
    assert box.stations is None and not box.stations_button.isEnabled()
    box.load_stations(tmp_path / "report.csv")                     # no SPECT to label: said, nothing read
    assert box.status.text() == "Load a SPECT first: a station table names the hot spots of a SPECT."
    assert box.nodes.labels == ["EXT L", "OBT R", "INT L"] and not panel.busy


def test_a_table_read_while_the_slider_moves_ends_with_both_and_none_while_a_file_is_read(qtbot, panel, spect,
                                                                                         tmp_path):
    box = loaded(qtbot, panel, spect)
    table = write_table(tmp_path / "report.csv", STATIONS)
    box.threshold_slider.setValue(40)                              # its re-segmentation is due: run after the table
    box.load_stations(table)
    box.threshold_slider.setValue(45)                              # moved while the table is read: after it, with it
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    assert box.status.text() == "3 nodes above 0.45 x maximum in spect.dcm, stations from report.csv"
    assert stations_of(box.nodes) == [STATIONS[i] for i in box.nodes.ids]
    box.load(spect)                                                # the stations of a SPECT not shown yet: refused
    box.load_stations(table)
    assert box.status.text() == "Wait until the file being read is shown, then read the stations of its SPECT."
    qtbot.waitUntil(lambda: not panel.busy, timeout=TIMEOUT_MS)
    assert box.stations is None and set(box.nodes.labels) <= {"L", "R"}
