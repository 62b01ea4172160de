"""The recorded video's encoding: the nodes tracked on the decoded video stay within 0.3 mm of those tracked on the
originals (issue 36 made the recording 4:4:4 JPEG for its CPU at full-HD stereo: this guards any change), decoders
give the frames back in their colours, in the recording's JPEG and in the x264 of sessions recorded before, and a
segment keeps its codec."""

import av
import cv2
import numpy as np
import pytest

from conftest import poll

from snreg.session.video import (RecordedPairs, StereoRecorder, VideoReader, VideoSegment, count_frames,
                                 rows_with_video, segment_files)
from snreg.session.video_writer import JPEG_444, OPENCV_JPEG, X264_444, Encoding, VideoFileWriter, recording


def _frames(n: int, width: int = 160, height: int = 120) -> list[np.ndarray]:
    """Coloured bars (blue, green, red, a saturated green as the stripes') over a gradient, shifted per frame."""
    out = []
    for k in range(n):
        image = np.zeros((height, width, 3), np.uint8)
        image[:] = np.linspace(20, 230, width, dtype=np.uint8)[None, :, None]
        for i, colour in enumerate([(255, 0, 0), (0, 255, 0), (0, 0, 255), (40, 200, 30)]):
            image[10 + 25 * i:30 + 25 * i, 10 + 3 * k:70 + 3 * k] = colour
        out.append(image)
    return out


def _write(path, encoding: Encoding, frames) -> None:
    writer = VideoFileWriter(path, frames[0].shape[1], frames[0].shape[0], 30.0, encoding)
    for k, image in enumerate(frames):
        writer.write(image, k)
    writer.close()


@pytest.mark.parametrize("encoding", [JPEG_444, X264_444], ids=["jpeg", "x264"])
def test_recorded_files_read_back_in_their_colours_with_pyav_and_opencv(tmp_path, encoding):
    frames, path = _frames(12), tmp_path / "v.mkv"
    _write(path, encoding, frames)
    assert count_frames(path) == len(frames)
    with VideoReader(path, 30.0) as reader:             # what review and retrack read, by frame number in any order
        for k in (7, 0, 11, 3):
            assert np.abs(reader.read(k).astype(int) - frames[k]).mean() < 2.0
        assert reader.read(12) is None
    capture = cv2.VideoCapture(str(path))
    for image in frames:
        ok, decoded = capture.read()
        assert ok and np.abs(decoded.astype(int) - image).mean() < 2.0
    capture.release()


def test_a_segment_records_the_encoding_of_its_size_and_keeps_the_one_it_was_recorded_with():
    assert recording(1920, 1080) == JPEG_444 and JPEG_444.codec == OPENCV_JPEG       # issue 36: under a core
    assert recording(1280, 720) == recording(960, 540) == X264_444                  # smaller: x264, as before
    full_hd = VideoSegment(0, ("a", "b"), 0, 30.0, 1920, 1080)
    assert full_hd.codec == "mjpeg yuvj444p quality 85 chroma 95 (libjpeg-turbo)"
    assert VideoSegment(0, ("a", "b"), 0, 30.0, 960, 540).codec == "libx264 yuv444p crf 18 tune psnr"
    before = dict(full_hd.to_json(), codec=X264_444.describe())                      # full HD recorded before issue 36
    assert VideoSegment.from_json(before).codec == X264_444.describe()


def test_the_full_hd_recording_writes_4_4_4_jpeg_key_frames(tmp_path):
    path = tmp_path / "v.mkv"
    _write(path, recording(1920, 1080), _frames(4))
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "mjpeg" and stream.codec_context.pix_fmt == "yuvj444p"
        assert all(packet.is_keyframe for packet in container.demux(stream) if packet.size)
    with pytest.raises(ValueError, match="yuvj444p"):
        VideoFileWriter(tmp_path / "w.mkv", 160, 120, 30.0, Encoding(OPENCV_JPEG, "yuvj420p", {"quality": "90"}))


@pytest.mark.parametrize("width, height, codec", [(320, 240, "h264"), (1280, 800, "mjpeg")])
def test_the_recorder_writes_both_eyes_in_the_encoding_of_their_size(tmp_path, width, height, codec):
    frames = _frames(6, width, height)
    session = tmp_path / "s.h5"
    recorder = StereoRecorder(session, VideoSegment(0, segment_files(session, 0), 0, 30.0, width, height))
    assert poll(lambda: recorder.ready)
    for k, image in enumerate(frames):                  # the queue holds them all: none is dropped
        assert recorder.offer(image, frames[-1 - k])
    segment = recorder.close()
    assert segment.closed and segment.frames == (6, 6) and segment.dropped == 0 and not segment.stopped
    assert segment.codec == recording(width, height).describe()
    for side in range(2):
        with av.open(str(segment.path(session, side))) as container:
            context = container.streams.video[0].codec_context
            assert (context.name, context.pix_fmt) == (codec, recording(width, height).pixel_format)
        with VideoReader(segment.path(session, side), 30.0) as reader:
            for k in (4, 1):
                expected = frames[k] if side == 0 else frames[-1 - k]
                assert np.abs(reader.read(k).astype(int) - expected).mean() < 2.0


@pytest.mark.slow
def test_nodes_on_the_decoded_video_stay_within_0_3_mm_of_the_originals(tmp_path):
    from snreg.camera import thesis_calibration
    from snreg.demo.scene import PhantomScene, Schedule
    from snreg.probe import default_probe_model
    from snreg.simulation.video_bench import _nodes, decode, write
    from snreg.tracking import StereoTracker

    cameras, probe = thesis_calibration().scaled(0.5), default_probe_model()
    scene = PhantomScene(cameras, probe, Schedule(rest_frames=5, move_frames=2), seed=4)
    pairs = [scene.render(k) for k in range(scene.schedule.cycle)]
    paths = [str(tmp_path / f"{side}.mkv") for side in ("left", "right")]
    for side, path in enumerate(paths):        # with the encoding the recorder's encoder process writes at 960x540
        write("av", path, recording(960, 540), [pair[side] for pair in pairs])
    decoded = list(zip(*(decode(path) for path in paths)))
    assert len(decoded) == len(pairs)
    tracker = StereoTracker(cameras, probe)
    truth, after = _nodes(tracker, scene, pairs), _nodes(tracker, scene, decoded)
    assert np.isfinite(truth).all()
    # this rendering (960x540) moves the nodes 0.08 mm in the recording's x264 4:4:4 CRF 18 (0.55 at CRF 20, 1.0 in
    # 4:2:0); 0.22 in the full-HD recording's JPEG (luma 85 chroma 95), 0.06 at luma 75, 0.47 at quality 90
    assert np.linalg.norm(after - truth, axis=1).max() < 0.3


def test_a_segment_recorded_in_x264_before_reads_back_pair_by_pair(tmp_path):
    """Sessions recorded before issue 36 hold x264 files: review, retrack and replay read any segment through
    RecordedPairs, which decodes whatever codec a file holds."""
    frames = _frames(8)
    session = tmp_path / "old.h5"
    files = segment_files(session, 0)
    for side in range(2):
        _write(tmp_path / files[side], X264_444, frames if side == 0 else frames[::-1])
    old = VideoSegment.from_json(dict(VideoSegment(0, files, 3, 30.0, 160, 120).to_json(),
                                      codec=X264_444.describe(), closed=True, frames=[8, 8]))
    assert old.codec == "libx264 yuv444p crf 18 tune psnr"
    assert rows_with_video(session, [old], 12).tolist() == [False] * 3 + [True] * 8 + [False]
    pairs = RecordedPairs(session, [old])
    try:
        for row in (9, 3, 10):
            left, right = pairs.pair(row)
            assert np.abs(left.astype(int) - frames[row - 3]).mean() < 2.0
            assert np.abs(right.astype(int) - frames[::-1][row - 3]).mean() < 2.0
        assert pairs.pair(11) is None
    finally:
        pairs.close()


@pytest.mark.slow
def test_the_surgery_scenes_node_on_the_decoded_full_hd_video_stays_within_0_3_mm(tmp_path):
    """Issue 36: the camera over textured tissue at full HD, the rest (seed 0, node 2: 117 mm deep) where JPEG at
    luma quality 75 moved the node 0.43 mm (0.36 over these 8 frames); the recording's encoding must keep it within
    0.3 mm (luma 85: 0.03 mm, x264 CRF 18: 0.06 mm)."""
    from snreg.camera import thesis_calibration
    from snreg.demo.scene import Schedule
    from snreg.demo.surgery_scene import SurgeryScene
    from snreg.probe import default_probe_model
    from snreg.simulation.video_bench import decode, fixes, nodes_of, write
    from snreg.tracking import StereoTracker

    cameras, probe = thesis_calibration(), default_probe_model()
    scene = SurgeryScene(cameras, probe, Schedule(rest_frames=30, move_frames=5), seed=0)
    first = scene.tour.rest_starts[2]
    pairs = [scene.render(k) for k in range(first, first + 8)]
    assert pairs[0][0].shape == (1080, 1920, 3)
    paths = [str(tmp_path / f"{side}.mkv") for side in ("left", "right")]
    for side, path in enumerate(paths):
        write("av", path, recording(1920, 1080), [pair[side] for pair in pairs])
    decoded = list(zip(*(decode(path) for path in paths)))
    assert len(decoded) == len(pairs)
    tracker, node_of = StereoTracker(cameras, probe), [2] * len(pairs)
    truth, after = (nodes_of(fixes(tracker, frames, node_of), node_of)[2] for frames in (pairs, decoded))
    assert np.isfinite(truth).all()
    assert np.linalg.norm(after - truth) < 0.3
