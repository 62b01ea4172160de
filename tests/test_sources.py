"""Frame sources: video files through the real capture classes, image folders, the callable source.

Every frame is a flat colour that encodes its eye and its index (robust to MJPG), so order,
eye and splitting are checked on the decoded pixels. There is no camera here: the device
classes are driven with video files, which run the same code after the capture objects.
"""

import time

import cv2
import numpy as np
import pytest

from snreg.sources import (CallableSource, ImageFolderSource, OpenCVPairSource, OpenCVStackedSource, SourceError,
                           SourceState, StereoFrame, VideoFilePairSource)

W, H = 64, 48          # multiples of 16: MJPG blocks never straddle the two eyes of a stacked frame
FPS = 25.0
EYE_GREEN = {"left": 60, "right": 180}


def coded(index: int, eye: str, w: int = W, h: int = H) -> np.ndarray:
    """A flat BGR image: blue = 20 + 16 * index (index < 14), green = the eye's code."""
    return np.full((h, w, 3), (20 + 16 * index, EYE_GREEN[eye], 100), np.uint8)


def decode(image: np.ndarray) -> tuple[int, str]:
    """(index, eye) of a coded image, read back from its centre (MJPG changes values by a few grey levels)."""
    b, g, _ = image[4:-4, 4:-4].reshape(-1, 3).mean(axis=0)
    eye = min(EYE_GREEN, key=lambda e: abs(EYE_GREEN[e] - g))
    code = (b - 20) / 16
    assert abs(EYE_GREEN[eye] - g) < 8 and abs(code - round(code)) < 0.35, (b, g)
    return round(code), eye


def write_video(path, images) -> str:
    h, w = images[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (w, h))
    assert writer.isOpened(), "MJPG in .avi should be writable with opencv-python-headless"
    for image in images:
        writer.write(image)
    writer.release()
    return str(path)


@pytest.fixture
def video_pair(tmp_path):
    def make(n_left=8, n_right=8):
        left = write_video(tmp_path / "left.avi", [coded(i, "left") for i in range(n_left)])
        right = write_video(tmp_path / "right.avi", [coded(i, "right") for i in range(n_right)])
        return left, right
    return make


def assert_frame(frame: StereoFrame, index: int, shape=(H, W, 3)):
    assert frame.index == index
    assert frame.left.shape == frame.right.shape == shape
    assert frame.left.dtype == frame.right.dtype == np.uint8
    assert decode(frame.left) == (index, "left") and decode(frame.right) == (index, "right")


def test_video_file_pair_reads_every_frame_in_order_with_file_timestamps(video_pair):
    with VideoFilePairSource(*video_pair()) as source:
        frames = list(source)
    assert len(frames) == 8
    for i, frame in enumerate(frames):
        assert_frame(frame, i)
        assert frame.t_left_ns == frame.t_right_ns == round(i * 1e9 / FPS)


def test_video_file_replay_is_deterministic(video_pair):
    paths = video_pair()
    runs = []
    for _ in range(2):
        with VideoFilePairSource(*paths) as source:
            runs.append([(f.t_left_ns, f.t_right_ns, f.left.tobytes(), f.right.tobytes()) for f in source])
    assert runs[0] == runs[1]


def test_end_of_file_ends_the_source_with_a_sentence_and_no_exception(video_pair):
    left, right = video_pair(n_left=8, n_right=5)
    source = VideoFilePairSource(left, right)
    frames = [source.read() for _ in range(5)]
    assert all(f is not None for f in frames) and source.state is SourceState.OPEN and source.problem == ""
    assert source.read() is None
    assert source.state is SourceState.ENDED
    assert source.problem == f"Right video file {right!r} ended after 5 frames."
    assert source.read() is None and source.read() is None
    source.close()
    assert source.state is SourceState.ENDED and "ended after 5 frames" in source.problem


def test_device_pair_code_on_files_uses_host_time_at_grab(video_pair):
    before = time.perf_counter_ns()
    with OpenCVPairSource(*video_pair()) as source:
        frames = list(source)
    after = time.perf_counter_ns()
    assert len(frames) == 8
    for i, frame in enumerate(frames):
        assert_frame(frame, i)
        assert before < frame.t_left_ns <= frame.t_right_ns < after   # left is grabbed first
        assert frame.skew_ms < 50.0
    assert all(a.t_left_ns < b.t_left_ns for a, b in zip(frames, frames[1:]))


def test_a_device_that_stops_delivering_is_lost_after_the_tolerated_failures(video_pair):
    source = OpenCVPairSource(*video_pair(n_left=3, n_right=3), tolerated_failures=2)
    assert [source.read().index for _ in range(3)] == [0, 1, 2]
    assert source.read() is None and source.state is SourceState.OPEN       # one failed read is tolerated ...
    assert source.read() is None and source.state is SourceState.OPEN
    assert source.read() is None and source.state is SourceState.LOST       # ... until there are too many
    assert source.problem.startswith("Left camera ") and "stopped delivering frames after 3 frames" in source.problem
    assert source.problem.endswith("reconnect it and open the source again.")
    assert source.read() is None


def test_a_device_that_drops_out_briefly_stays_open(video_pair, monkeypatch):
    """Single failed grabs between good ones (a USB glitch) return None but never add up to 'lost'."""
    real_capture = cv2.VideoCapture

    class FlakyCapture:
        def __init__(self, device, backend):
            self.capture, self.calls = real_capture(device, backend), 0
            self.flaky = device.endswith("left.avi")

        def grab(self):
            self.calls += 1
            return not (self.flaky and self.calls in (2, 4, 6)) and self.capture.grab()

        def isOpened(self):
            return self.capture.isOpened()

        def retrieve(self):
            return self.capture.retrieve()

        def release(self):
            self.capture.release()

    monkeypatch.setattr(cv2, "VideoCapture", FlakyCapture)
    source = OpenCVPairSource(*video_pair(), tolerated_failures=1)
    results = [source.read() for _ in range(11)]
    assert source.state is SourceState.OPEN
    assert [None if f is None else f.index for f in results] == [0, None, 1, None, 2, None, 3, 4, 5, 6, 7]
    for i, frame in enumerate(f for f in results if f is not None):
        assert_frame(frame, i)


@pytest.mark.parametrize("layout, size", [("side_by_side", (2 * W, H)), ("top_bottom", (W, 2 * H))])
def test_stacked_device_splits_each_frame_into_left_then_right(tmp_path, layout, size):
    axis = 1 if layout == "side_by_side" else 0
    images = [np.concatenate([coded(i, "left"), coded(i, "right")], axis=axis) for i in range(6)]
    assert images[0].shape[:2] == size[::-1]
    path = write_video(tmp_path / "stacked.avi", images)
    with OpenCVStackedSource(path, layout) as source:
        frames = list(source)
    assert len(frames) == 6
    for i, frame in enumerate(frames):
        assert_frame(frame, i)
        assert frame.t_left_ns == frame.t_right_ns
        assert frame.left.flags.c_contiguous and frame.right.flags.c_contiguous
    assert source.state is SourceState.LOST and "stopped delivering frames after 6 frames" in source.problem


def test_unknown_stacked_layout_is_refused(tmp_path):
    path = write_video(tmp_path / "stacked.avi", [coded(0, "left")])
    with pytest.raises(SourceError, match="Unknown stereo layout 'interlaced'; use one of side_by_side, top_bottom"):
        OpenCVStackedSource(path, "interlaced")


def test_a_camera_that_does_not_exist_raises_a_source_error_that_says_what_to_do(video_pair):
    with pytest.raises(SourceError, match=r"^Cannot open camera 97: check that it is connected .* device index or path"):
        OpenCVPairSource(97, 98)
    left, _ = video_pair()
    with pytest.raises(SourceError, match="Cannot open camera 98"):
        OpenCVPairSource(left, 98)                     # the left capture opened, the right one did not
    with pytest.raises(SourceError, match="Cannot open camera 5"):
        OpenCVStackedSource(5)
    assert issubclass(SourceError, ValueError)


def test_a_camera_that_cannot_deliver_the_requested_size_is_refused(video_pair):
    with pytest.raises(SourceError, match=rf"delivers {W}x{H} frames, not the requested 1920x1080; choose a size"):
        OpenCVPairSource(*video_pair(), frame_size=(1920, 1080))
    with OpenCVPairSource(*video_pair(), frame_size=(W, H)) as source:
        assert_frame(source.read(), 0)


def test_missing_or_undecodable_video_files_raise_source_errors(video_pair, tmp_path):
    left, right = video_pair()
    missing = str(tmp_path / "missing.avi")
    with pytest.raises(SourceError, match=rf"^Video file '{missing}' does not exist; check the path\.$"):
        VideoFilePairSource(left, missing)
    text = tmp_path / "notes.avi"
    text.write_text("not a video")
    with pytest.raises(SourceError, match="Cannot decode video file .*notes.avi'; convert it"):
        VideoFilePairSource(str(text), right)


def test_closing_ends_the_source(video_pair):
    with VideoFilePairSource(*video_pair()) as source:
        assert source.read() is not None
    assert source.state is SourceState.ENDED and source.problem.endswith("was closed.")
    assert source.read() is None
    source.close()                                     # closing twice is harmless


def write_images(folder, eye, indices, ext=".png"):
    folder.mkdir(exist_ok=True)
    for i in indices:
        cv2.imwrite(str(folder / f"{eye}_{i}{ext}"), coded(i, eye))


def test_image_folder_pairs_by_natural_name_order_at_a_nominal_rate(tmp_path):
    for eye in ("left", "right"):
        write_images(tmp_path / eye, eye, range(12))     # left_2 must come before left_10
    source = ImageFolderSource(str(tmp_path / "left" / "*.png"), str(tmp_path / "right" / "*.png"),
                               fps=20.0, start_ns=5_000)
    assert len(source) == 12
    frames = list(source)
    assert [f.index for f in frames] == list(range(12))
    for i, frame in enumerate(frames):
        assert_frame(frame, i)
        assert frame.t_left_ns == frame.t_right_ns == 5_000 + i * 50_000_000
    assert source.state is SourceState.ENDED and source.problem.startswith("All 12 image pairs of ")
    assert source.read() is None


def test_image_folder_refuses_unmatched_or_missing_images(tmp_path):
    write_images(tmp_path, "left", range(3))
    write_images(tmp_path, "right", range(2))
    with pytest.raises(SourceError, match="3 left images match .* but 2 right images match .*one right partner"):
        ImageFolderSource(str(tmp_path / "left_*.png"), str(tmp_path / "right_*.png"))
    with pytest.raises(SourceError, match=r"No right images match .*'; check the folder and the pattern\."):
        ImageFolderSource(str(tmp_path / "left_*.png"), str(tmp_path / "none_*.png"))
    with pytest.raises(SourceError, match="frame rate must be a positive"):
        ImageFolderSource(str(tmp_path / "left_*.png"), str(tmp_path / "left_*.png"), fps=0)


def test_an_unreadable_image_loses_the_source_without_raising(tmp_path):
    write_images(tmp_path, "left", range(4))
    write_images(tmp_path, "right", range(4))
    (tmp_path / "right_2.png").write_bytes(b"broken")
    source = ImageFolderSource(str(tmp_path / "left_*.png"), str(tmp_path / "right_*.png"))
    assert [source.read().index for _ in range(2)] == [0, 1]
    assert source.read() is None
    assert source.state is SourceState.LOST and "right_2.png' cannot be read" in source.problem


def test_callable_source_renders_at_a_nominal_rate_then_ends():
    calls = []

    def render(i):
        calls.append(i)
        return coded(i, "left"), coded(i, "right")

    source = CallableSource(render, fps=30.0, n_frames=5, start_ns=1_000)
    frames = list(source)
    assert calls == [0, 1, 2, 3, 4]
    for i, frame in enumerate(frames):
        assert_frame(frame, i)
        assert frame.t_left_ns == frame.t_right_ns == 1_000 + round(i * 1e9 / 30.0)
    assert source.state is SourceState.ENDED and source.problem == "Synthetic source rendered all 5 frames."
    assert source.read() is None and calls == [0, 1, 2, 3, 4]


def test_endless_callable_source_stays_open_until_closed():
    with CallableSource(lambda i: (coded(i % 10, "left"), coded(i % 10, "right")), fps=60.0) as source:
        frames = [source.read() for _ in range(100)]
        assert source.state is SourceState.OPEN and frames[-1].index == 99
        assert frames[-1].t_left_ns == round(99 * 1e9 / 60.0)
    assert source.state is SourceState.ENDED and source.read() is None


def test_a_live_callable_source_stamps_at_grab_and_skips_what_a_slow_consumer_missed():
    """As a camera (docs/design.md, Conventions): frame k is due k / fps after the first read; a consumer 95 ms late at 100 Hz
    gets the newest due frame (9 skipped), stamped with the host time it was grabbed: when it was due, the instant
    the scene shows, not when the late consumer took it."""
    clock = {"ns": 7_000_000_000}
    calls = []

    def render(i):
        calls.append(i)
        return coded(i % 10, "left"), coded(i % 10, "right")

    source = CallableSource(render, fps=100.0, n_frames=30, live=True, clock=lambda: clock["ns"])
    first = source.read()
    assert (first.index, first.t_left_ns, first.t_right_ns) == (0, 7_000_000_000, 7_000_000_000)
    clock["ns"] += 95_000_000 + 10_000_000          # the consumer took 105 ms: frames 1..9 are gone
    late = source.read()
    assert (late.index, late.t_left_ns) == (10, 7_100_000_000) and calls == [0, 10]
    clock["ns"] += 10_000_000
    assert source.read().index == 11                 # keeping up: no skip
    clock["ns"] += 1_000_000_000
    assert source.read() is None and source.state is SourceState.ENDED      # frame 111 is past the 30 it has


def test_a_live_callable_source_counts_its_frames_from_a_given_epoch():
    """Another process shows the same scene from the same instant (the demo's IMU): frame k is due k / fps after
    ``epoch_ns``, whenever the first read comes."""
    clock = {"ns": 5_000_000_000}
    source = CallableSource(lambda i: (coded(i % 10, "left"), coded(i % 10, "right")), fps=50.0, live=True,
                            clock=lambda: clock["ns"], epoch_ns=4_000_000_000)
    first = source.read()                            # 1 s after the epoch: frame 50 is due
    assert (first.index, first.t_left_ns) == (50, 5_000_000_000)
    clock["ns"] += 30_000_000
    assert (source.read().index, source.read().index) == (51, 52)


def test_stereo_frames_must_be_bgr_uint8_images():
    good = coded(0, "left")
    frame = StereoFrame(good, good, 1_000_000, 3_500_000, 0)
    assert frame.skew_ms == 2.5
    with pytest.raises(ValueError, match="right image must be an HxWx3 uint8 BGR array, not a float64 array"):
        StereoFrame(good, good.astype(float), 0, 0, 0)
    with pytest.raises(ValueError, match="left image must be an HxWx3 uint8 BGR array, not a uint8 array of shape"):
        StereoFrame(good[..., 0], good, 0, 0, 0)
    bad = CallableSource(lambda i: (good, None), fps=30.0)
    with pytest.raises(ValueError, match="not a NoneType"):
        bad.read()
