"""Issue 35: a demo that cannot store every node says why (per rest), leaves its output free for the retry and keeps
what it recorded; the interactive demo's rests leave time to press Store SN."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from snreg.cli import main
from snreg.demo import headless
from snreg.demo.rest_log import RestLog
from snreg.demo.rig import DEMO_FPS, DemoRig, interactive_schedule
from snreg.demo.staging import publish, staging_folder
from snreg.session import Session
from snreg.workflow import acquisition
from snreg.workflow.acquisition import THESIS_FIXES_PER_NODE

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)


def _outcome(spread: float, fix: bool = True):
    return SimpleNamespace(fix=object() if fix else None, window_spread_mm=spread)


def test_the_rest_log_names_each_unstored_nodes_best_spread_on_every_rest():
    log = RestLog()
    for rest in range(3):                       # node 0 stored on the first rest; node 1 never still; node 2 never full
        for spread in (0.1, 3.0, 1.7 + 0.1 * rest, 2.5):         # the first window still holds the move
            log.add(1, _outcome(spread), window=2)
        log.add(None, _outcome(np.nan))
        for _ in range(4):
            log.add(2, _outcome(5.0, fix=rest > 0), window=5)     # spreads of windows holding the move
        log.add(None, _outcome(np.nan))
        log.add(0, _outcome(0.4), stored=rest == 0)
        log.add(None, _outcome(np.nan))
    assert [(v.node, v.frames) for v in log.visits[:3]] == [(1, 4), (2, 4), (0, 1)] and len(log.visits) == 9
    assert log.visits[0].best_spread_mm == pytest.approx(1.7) and log.visits[2].stored
    why = log.why_missing({0}, ("A", "B", "C", "D"), fixes_per_node=60, still_mm=1.0)
    assert why == ("node B: its best window spread on 3 rests was 1.70, 1.80, 1.90 mm; auto-store needs 1.00 mm or "
                   "less; node C: the store window never filled on 3 rests (at most 4 valid fixes of 60 in 4 frames "
                   "processed while resting: the live feed skips frames when tracking falls behind; a loaded computer "
                   "processes too few); node D was never reached")
    assert log.why_missing({0, 1, 2, 3}, ("A", "B", "C", "D"), fixes_per_node=60, still_mm=1.0) == ""


def test_a_staged_run_moves_out_whole_and_never_replaces_a_file_that_appeared(tmp_path):
    target = tmp_path / "d.h5"
    folder = staging_folder(target)
    assert folder.parent == tmp_path and folder.name.startswith(".d.h5.partial-")
    assert staging_folder(target) != folder                        # a killed run's folder is never reused
    for name in ("d.h5", "d.h5.journal", "d.left.mkv", "d-spect.dcm"):
        (folder / name).write_text(name)
    (tmp_path / "d.left.mkv").write_text("someone else's")
    with pytest.raises(OSError, match="d.left.mkv appeared while the demo ran; the run is kept in"):
        publish(folder, target)
    assert not target.exists() and (folder / "d.h5").read_text() == "d.h5"     # nothing moved
    (tmp_path / "d.left.mkv").unlink()
    (tmp_path / "d-spect.dcm").write_text("old")                   # the SPECT may be replaced, as before
    publish(folder, target, replaceable=("d-spect.dcm",))
    assert not folder.exists()
    assert {p.name: p.read_text() for p in tmp_path.iterdir() if not p.name.startswith(".")} == {
        n: n for n in ("d.h5", "d.h5.journal", "d.left.mkv", "d-spect.dcm")}


@pytest.mark.slow
def test_a_failed_demo_names_each_rests_best_spread_and_the_same_command_runs_again(tmp_path, capsys, monkeypatch):
    path = tmp_path / "d.h5"
    monkeypatch.setattr(acquisition, "STILL_SPREAD_MM", 0.0)     # nothing is ever held still enough: no auto-store
    monkeypatch.setattr(headless, "STILL_SPREAD_MM", 0.0)
    monkeypatch.setattr(headless, "_TOURS", 1)
    argv = ["demo", "--headless", "-o", str(path), "--fixes", "5", "--json"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "only 0 of 4 nodes were stored" in err and "was closed" not in err
    assert "node EXT R: its best window spread on 1 rest was " in err and "auto-store needs 0.00 mm or less" in err
    assert err.count("best window spread") == 4
    assert "was not written, so the same command can run again" in err
    assert not path.exists() and not Path(f"{path}.journal").exists()
    [kept] = [p for p in tmp_path.iterdir() if p.name.startswith(".d.h5.partial-")]
    assert str(kept) in err
    with Session.open(kept / "d.h5") as session:                  # the recording so far, readable
        assert len(session.stream("frames")) > 0 and session.intraop_records() == []
    monkeypatch.undo()
    argv[argv.index("5")] = "20"
    assert main(argv) == 0                                         # the retry is not refused
    out = json.loads(capsys.readouterr().out)
    assert len(out["nodes"]) == 4 and out["session"] == str(path)
    with Session.open(path) as session:                            # published whole: its videos found beside it
        assert len(session.intraop_records()) == 4
        assert all(video.path(path, side).exists() for video in session.videos() for side in (0, 1))
    assert (tmp_path / "d-spect.dcm").exists() and kept.exists()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".d.h5.partial-")) == [kept.name]


def test_the_interactive_demo_rests_leave_seconds_to_press_store_sn_and_the_headless_one_does_not_wait():
    rig_schedule = interactive_schedule()
    assert DemoRig.__init__.__kwdefaults__["schedule"] is None     # the GUI demo's rig takes the interactive rests
    window_s = THESIS_FIXES_PER_NODE / DEMO_FPS
    rest_s = rig_schedule.rest_frames / DEMO_FPS
    assert rest_s - window_s >= 10.0                               # "ready" at a full-rate feed
    assert rest_s - 2 * window_s >= 8.0                            # and when the feed processes every other frame
    # the headless demo's rests are held until stored (issue 35): nominally one window at the full rate and a second
    assert headless.rest_frames_for(THESIS_FIXES_PER_NODE) == THESIS_FIXES_PER_NODE + 30


def test_a_rests_frames_pair_every_left_exposure_with_every_right_one():
    from snreg.demo.rest_exposures import RestExposures

    bank = RestExposures((np.zeros(1), np.zeros(1)), lambda radiance, seed: (seed, -seed), 4, seed=10)
    assert bank.lefts == [10, 11, 12, 13] and bank.rights == [-10, -11, -12, -13]
    assert sorted(bank.choice(i) for i in range(16)) == [(a, b) for a in range(4) for b in range(4)]
    assert len({bank.pair(i) for i in range(100, 116)}) == 16                   # wherever the window starts
