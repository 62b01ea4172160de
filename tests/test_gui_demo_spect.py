"""``snreg-gui --demo``'s preop side (:class:`~snreg_gui.registration.demo_spect.DemoSpect`): the phantom's SPECT and
its report of stations written as ``snreg demo --headless`` writes them, both loaded into the panel (offscreen)."""

from types import SimpleNamespace

import numpy as np

from snreg.demo import phantom
from snreg.demo.phantom_preop import spect_path_for, stations_path_for, write_phantom_preop
from snreg.demo.scene import NODE_CENTRES_MM
from snreg.geometry import apply
from snreg.preop.segment import read_station_table
from snreg_gui.registration.demo_spect import DemoSpect

TIMEOUT_MS = 30_000


class PhantomOnly:
    """The two things DemoSpect asks of the demo rig: where the phantom's sources lie and its SPECT (no feeds)."""

    def phantom_sources_lps(self) -> np.ndarray:
        return apply(phantom.setup_patient_from_trocar(phantom.TRUE_TILT_DEG), NODE_CENTRES_MM)

    def write_phantom_spect(self, path):
        return phantom.write_phantom_spect(self.phantom_sources_lps(), path)


def test_the_gui_demo_loads_the_spect_with_its_stations_as_the_headless_demo_labels_them(qtbot, panel, tmp_path):
    messages = []
    session = tmp_path / "demo.h5"
    window = SimpleNamespace(rig=PhantomOnly(), session=SimpleNamespace(path=session), registration=panel,
                             statusBar=lambda: SimpleNamespace(showMessage=messages.append))
    demo = DemoSpect(window)
    box = panel.preop_box
    qtbot.waitUntil(lambda: box.nodes is not None and not panel.busy, timeout=TIMEOUT_MS)
    assert not messages and demo.path == spect_path_for(session) and demo.path.exists()
    report = read_station_table(stations_path_for(session))
    assert box.stations == report and sorted(set(report.values())) == ["EXT", "OBT"]
    assert box.status.text() == "4 nodes above 0.30 x maximum in demo-spect.dcm, stations from demo-stations.csv"
    # one question, one answer: the nodes the headless demo registers (its own files, written again elsewhere)
    (tmp_path / "again").mkdir()
    headless = write_phantom_preop(PhantomOnly(), tmp_path / "again" / "demo.h5")
    assert box.nodes.labels == headless.nodes.labels and box.nodes.ids == headless.nodes.ids
    np.testing.assert_allclose(box.nodes.xyz, headless.nodes.xyz)
    # each hot spot named by the station written on the phantom source it shows
    truth = phantom.hot_spot_of_sources(box.nodes.xyz, PhantomOnly().phantom_sources_lps())
    assert [box.nodes.labels[k].split()[0] for k in truth] == [label.split()[0] for label in phantom.PHANTOM_LABELS]
