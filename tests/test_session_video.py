"""The video recorded with a session: frames in step with streams/frames, re-tracking, integrity (verify), and what a
kill or a slow encoder leaves. One short recording of the rendered phantom at a quarter of the thesis resolution."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
import time

import h5py
import numpy as np
import pytest
from conftest import VIDEO_FIXES, start_video

from snreg.camera import StereoCalibration, load_calibration, thesis_calibration
from snreg.chain import ChainCalibration
from snreg.cli import main as cli_main
from snreg.demo.scene import NODE_CENTRES_MM
from snreg.probe import default_probe_model
from snreg.session import Session, SessionError
from snreg.session.export import session_info
from snreg.session.integrity import verify
from snreg.session.video import RECENT_DROP_PAIRS, RecorderState, VideoReader, count_frames, video_text
from snreg.sources import CallableSource
from snreg.workflow.acquisition import Acquisition, ImuReading
from snreg.workflow.retrack import retrack, store_retracked

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)

LEVEL = ImuReading(np.eye(3))


@pytest.mark.slow
def test_both_feeds_are_recorded_frame_for_frame_with_the_frame_rows(recorded_video):
    path, scene, _ = recorded_video
    info = session_info(path)
    rows = info["streams"]["frames"]
    assert info["intraop_nodes"] == len(NODE_CENTRES_MM) and not info["damaged"]
    assert [v["side"] for v in info["videos"]] == ["left", "right"]
    assert all(v["frames"] == rows == scene.schedule.cycle for v in info["videos"])
    with Session.open(path) as session:
        indices = session.stream("frames")["index"][()]
        [segment] = session.videos()
    assert segment.closed and segment.first_row == 0 and segment.dropped == 0
    for side in range(2):
        assert count_frames(segment.path(path, side)) == rows
        with VideoReader(segment.path(path, side), segment.fps) as reader:
            for k in (0, rows // 2, rows - 1, 3):                      # frame k is the pair of row k, in any order
                decoded = reader.read(k).astype(int)
                errors = [np.abs(decoded - scene.render(int(indices[k]) + step)[side]).mean() for step in (0, 1, 2)]
                assert errors[0] < 3.0 and np.argmin(errors) == 0     # the next frames: other noise, or moved
            assert reader.read(rows) is None


@pytest.mark.slow
def test_retrack_with_the_own_calibration_moves_little_and_a_longer_baseline_scales_the_range(recorded_video, tmp_path):
    path, _, cameras = recorded_video
    own = retrack(path)
    assert [n.fixes for n in own.nodes] == [VIDEO_FIXES] * len(NODE_CENTRES_MM)
    assert max(n.moved_mm for n in own.nodes) < 0.5
    for node in own.nodes:          # the same window again: the covariance the acquisition stored, computed anew
        np.testing.assert_allclose(node.after_cov, node.node.cov_trocar_mm2, atol=0.1)      # mm^2, of some 16
    longer = StereoCalibration.from_pair(cameras.image_size, cameras.K1, cameras.D1, cameras.K2, cameras.D2,
                                         cameras.R, cameras.T * 1.05)
    scaled = retrack(path, calibration=longer)
    ratios = [np.linalg.norm(n.after_camera) / np.linalg.norm(n.node.xyz_camera) for n in scaled.nodes]
    assert np.allclose(ratios, 1.05, atol=0.01)
    copy = tmp_path / "s.h5"
    shutil.copy(path, copy)
    for video in path.parent.glob("s.*.mkv"):
        shutil.copy(video, tmp_path / video.name)
    assert store_retracked(copy, scaled, "retrack: baseline 5% longer") == len(NODE_CENTRES_MM)
    with Session.open(copy) as session:
        [event] = session.events("nodes_reexpressed")
        nodes = session.intraop_records()
    assert event["reason"] == "retrack: baseline 5% longer"
    assert np.allclose([c["old"]["xyz_camera"] for c in event["nodes"]], [n.node.xyz_camera for n in scaled.nodes])
    assert np.allclose([n.xyz_camera for n in nodes], [n.after_camera for n in scaled.nodes])
    np.testing.assert_allclose([n.cov_trocar_mm2 for n in nodes], [n.after_cov for n in scaled.nodes])


@pytest.mark.slow
def test_retrack_refuses_another_image_size_and_a_session_without_video(recorded_video, tmp_path, capsys):
    path, _, _ = recorded_video
    with pytest.raises(SessionError, match="960x540 images but the session's video is 480x270"):
        retrack(path, calibration=thesis_calibration().scaled(0.5))
    bare = tmp_path / "bare.h5"
    with Session.create(bare, case_id="bare") as session:
        session.set_calibration(stereo=thesis_calibration())
    assert cli_main(["session", "retrack", str(bare), "--dry-run"]) == 2
    assert "has no recorded video" in capsys.readouterr().err


def test_export_calibration_writes_the_calibration_the_session_used(recorded_video, tmp_path):
    path, _, cameras = recorded_video
    out = tmp_path / "used.yaml"
    assert cli_main(["session", "export", str(path), "--format", "calibration", "-o", str(out)]) == 0
    again = load_calibration(out)
    assert again.image_size == cameras.image_size and np.allclose(again.T, cameras.T) and np.allclose(again.K1, cameras.K1)


def _stored_bytes(dataset: h5py.Dataset) -> list[tuple[int, int]]:
    """(offset, size) in the file of each piece of a dataset's stored data: its chunks (a variable-length dataset's
    chunk only as far as its rows reach: past them it holds nothing anyone reads)."""
    if dataset.chunks is None:
        offset = dataset.id.get_offset()
        return [] if offset is None else [(offset, dataset.id.get_storage_size())]
    pieces = [dataset.id.get_chunk_info(k) for k in range(dataset.id.get_num_chunks())]
    if h5py.check_dtype(vlen=dataset.dtype) is None:
        return [(p.byte_offset, p.size) for p in pieces if p.size]
    row_bytes = dataset.id.get_type().get_size() * int(np.prod(dataset.shape[1:], dtype=int))
    return [(p.byte_offset, min(p.size, (dataset.shape[0] - p.chunk_offset[0]) * row_bytes)) for p in pieces]


def _flip(path, offset: int) -> None:
    with open(path, "r+b") as file:
        file.seek(offset)
        byte = file.read(1)
        file.seek(offset)
        file.write(bytes([byte[0] ^ 0xFF]))


@pytest.mark.slow
def test_verify_reports_every_flipped_byte_and_names_what_it_damaged(recorded_video, tmp_path, capsys):
    path, _, _ = recorded_video
    assert verify(path).ok
    with h5py.File(path) as h5:
        names = []
        h5.visititems(lambda name, item: names.append(name) if isinstance(item, h5py.Dataset) else None)
        pieces = {name: _stored_bytes(h5[name]) for name in names}
        jpeg = bytes(h5["nodes/intraop/left_jpeg"][2])
    pieces = {name: p for name, p in pieces.items() if p}
    rng = np.random.default_rng(23)
    copy = tmp_path / "s.h5"
    for video in path.parent.glob("s.*.mkv"):
        shutil.copy(video, tmp_path / video.name)
    found = 0
    for trial in range(20):
        name = sorted(pieces)[rng.integers(len(pieces))]
        offset, size = pieces[name][rng.integers(len(pieces[name]))]
        shutil.copy(path, copy)
        _flip(copy, offset + int(rng.integers(size)))
        report = verify(copy, videos=False)
        found += not report.ok
        assert not report.ok, f"a flipped byte in {name} went unnoticed"
        assert any(name.split("/")[-1] in d.where or d.what in ("node", "event") for d in report.damaged), \
            (name, report.damaged)
        assert all(d.what != "video" for d in report.damaged)
    assert found == 20
    # a byte inside a snapshot JPEG (HDF5's global heap: no Fletcher-32 there) names the node and the snapshot
    shutil.copy(path, copy)
    _flip(copy, copy.read_bytes().index(jpeg) + len(jpeg) // 2)
    report = verify(copy, videos=False)
    assert [d.to_json() for d in report.damaged] == [{"what": "node", "where": "nodes/intraop row 2 (SN3)",
                                                      "why": "its left snapshot JPEG differs from its SHA-256"}]
    assert session_info(copy)["damaged"]
    # a damaged video: its SHA-256 no longer matches; the command says so and exits 1
    shutil.copy(path, copy)
    _flip(tmp_path / "s.right.mkv", 5000)
    assert cli_main(["session", "verify", str(copy), "--json"]) == 1
    damaged = json.loads(capsys.readouterr().out)["damaged"]
    assert damaged == [{"what": "video", "where": str(tmp_path / "s.right.mkv"),
                        "why": "its SHA-256 differs from the one recorded when it was closed"}]


_RECORDER = textwrap.dedent("""
    import sys, time, numpy as np
    from snreg.session import Session
    rng = np.random.default_rng(0)
    with Session.create(sys.argv[1], case_id="kill") as session:
        session.start_video(30.0, 160, 120)
        while not session.video_state().started:
            time.sleep(0.01)
        logged = 0
        for k in range(100000):
            image = np.full((120, 160, 3), k % 256, np.uint8)
            image[:, :8] = rng.integers(0, 256, (120, 8, 3))
            logged += session.append_frame_pair(time.perf_counter_ns(), time.perf_counter_ns(), k, image, image)
            if logged == 30:                 # a second of pairs taken by the encoder, each with its frame row
                print("recording", flush=True)
            elif k == 600 and logged < 30:   # 20 s: the encoder is not taking pairs; say so instead of hanging
                print(f"the encoder took {logged} of 600 pairs", flush=True)
                break
            time.sleep(1 / 30)
""")


@pytest.mark.slow
def test_a_killed_recording_keeps_the_frames_it_logged_readable(tmp_path):
    path = tmp_path / "k.h5"
    process = subprocess.Popen([sys.executable, "-c", _RECORDER, str(path)], stdout=subprocess.PIPE)
    assert process.stdout.readline().strip() == b"recording"
    time.sleep(2.5)
    process.kill()
    process.wait()
    time.sleep(0.5)                                  # the encoder finishes its files once its input closes
    with Session.open(path) as session:
        rows = session.stream("frames").shape[0]
        [segment] = session.videos()
    assert not segment.closed and rows > 30
    report = verify(path)
    assert report.ok and any("never closed" in note for note in report.unproven)
    for side in range(2):
        assert count_frames(segment.path(path, side)) >= 0.9 * rows


@pytest.mark.slow
def test_pairs_the_encoder_cannot_keep_up_with_are_counted_and_leave_no_row(tmp_path, monkeypatch):
    import snreg.session.video as video
    monkeypatch.setattr(video, "QUEUE_PAIRS", 1)
    image = np.random.default_rng(1).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    path = tmp_path / "d.h5"
    with Session.create(path, case_id="drop") as session:
        start_video(session, 30.0, 320, 240)
        taken = [session.append_frame_pair(k, k, k, image, image) for k in range(40)]
        state = session.video_state()
        assert state.dropped == taken.count(False) > 0
        assert "DROPPED (encoder behind)" in video_text(state)       # the last drop is news: the line's alarm
    with Session.open(path) as session:
        [segment] = session.videos()
        rows = session.stream("frames")["index"][()]
    assert segment.dropped == taken.count(False) and segment.frames == (len(rows), len(rows))
    assert list(rows) == [k for k, ok in enumerate(taken) if ok]


def test_drops_are_an_alarm_while_recent_and_history_once_the_encoder_keeps_up():
    state = RecorderState(started=True, written=300, dropped=4, written_at_drop=300, free_bytes=56 * 10**9)
    assert video_text(state) == "video: recording, 300 frames, 4 DROPPED (encoder behind), 56 GB free"
    state.written = 300 + RECENT_DROP_PAIRS - 1
    assert "4 DROPPED (encoder behind)" in video_text(state)
    state.written = 300 + RECENT_DROP_PAIRS
    assert video_text(state) == f"video: recording, {state.written} frames, 4 dropped earlier, 56 GB free"
    assert "DROPPED" in video_text(RecorderState(started=True, written=10, dropped=1, written_at_drop=10))
    assert "dropped" not in video_text(RecorderState(started=True, written=10))


def test_too_little_free_space_records_no_video_and_says_so(tmp_path, monkeypatch):
    cameras = thesis_calibration().scaled(0.25)
    with Session.create(tmp_path / "f.h5", case_id="full") as session:
        with pytest.raises(OSError, match="GB free beside f.h5"):
            session.start_video(30.0, 480, 270, min_free_bytes=10**18)
        assert session.videos() == [] and not list(tmp_path.glob("*.mkv"))

        def full(*args, **kwargs):
            raise OSError("only 0.1 GB free")
        monkeypatch.setattr(session, "start_video", full)
        acquisition = Acquisition(cameras, default_probe_model(), ChainCalibration.manual(), session,
                                  video_fps=30.0)
        frame = next(iter(CallableSource(lambda k: (np.zeros((270, 480, 3), np.uint8),) * 2, 30.0, 1)))
        outcome = acquisition.process(frame, LEVEL)
        assert outcome.video == "video: not recorded (only 0.1 GB free)"
        assert session.events("video_not_recorded")[0]["reason"] == "only 0.1 GB free"
    with Session.open(tmp_path / "f.h5") as session:
        assert session.stream("frames").shape[0] == 1          # the session goes on without video


@pytest.mark.slow
def test_turning_recording_off_closes_the_segment_recorded_so_far(tmp_path):
    cameras = thesis_calibration().scaled(0.125)
    frame = next(iter(CallableSource(lambda k: (np.zeros((135, 240, 3), np.uint8),) * 2, 30.0, 1)))
    with Session.create(tmp_path / "o.h5", case_id="off") as session:
        start_video(session, 30.0, 240, 135)
        Acquisition(cameras, default_probe_model(), ChainCalibration.manual(), session, video_fps=30.0).process(
            frame, LEVEL)
        assert session.video_state() is not None
        off = Acquisition(cameras, default_probe_model(), ChainCalibration.manual(), session)
        assert session.video_state() is None and session.videos()[0].closed
        assert off.process(frame, LEVEL).video == "video: off (turned off in the settings)"
    with Session.open(tmp_path / "o.h5") as session:
        assert session.stream("frames").shape[0] == 2 and session.videos()[0].frames == (1, 1)


def test_recover_into_another_folder_takes_the_video_along(recorded_video, tmp_path):
    from snreg.session.recovery import recover

    path, _, _ = recorded_video
    out = tmp_path / "elsewhere" / "clean.h5"
    out.parent.mkdir()
    report = recover(path, out)
    assert sorted(report.carried) == ["clean.left.mkv", "clean.right.mkv"]
    assert "beside the recovered file: clean.left.mkv, clean.right.mkv" in "\n".join(report.lines())
    checked = verify(out)                                              # sizes and SHA-256 as recorded
    assert checked.ok and [video["path"] for video in checked.videos] == [str(out.with_name("clean.left.mkv")),
                                                                           str(out.with_name("clean.right.mkv"))]
    with Session.open(out) as session:
        assert session.videos()[0].files == ("clean.left.mkv", "clean.right.mkv")
    assert path.with_name("s.left.mkv").exists()                       # the original stays where it was
    again = tmp_path / "elsewhere" / "clean2.h5"
    (tmp_path / "elsewhere" / "clean2.left.mkv").write_bytes(b"someone else's")
    with pytest.raises(SessionError, match="already exists"):
        recover(path, again)
