"""Which codec and container to record a session's video with: ``python -m snreg.simulation.video_bench [--scale S]``.

Why: the choice (docs/guide/review.md, "Recorded video") rests on four measurements per candidate, on the demo's
rendered phantom tour (sensor noise sigma 2, the worst case for compression; ``--scene surgery`` the camera moving
over tissue, ``--noise`` another sigma): the largest distance between a node tracked on the decoded frames and on
the originals (median of each rest's fixes), the size of an hour of stereo 1080p30 (measured at ``scale`` of 1080p
and scaled by the pixel count), the encoder's CPU seconds per second of stereo video (``--rounds``: the median of
several writes taking turns), and whether a file whose writer is killed (SIGKILL, nothing closed) still decodes its
frames. Candidates: OpenCV's ``VideoWriter`` (its MJPEG, and the FFmpeg inside the wheel) and the recorder's own
:class:`~snreg.session.video_writer.VideoFileWriter` (PyAV's encoders, libx264 among them, and OpenCV's JPEG).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from snreg.camera import thesis_calibration
from snreg.demo.scene import PhantomScene, Schedule
from snreg.demo.surgery_scene import SurgeryScene
from snreg.probe import default_probe_model
from snreg.session.video_writer import JPEG_444, OPENCV_JPEG, Encoding, VideoFileWriter
from snreg.tracking import StereoTracker, TrackingError, summarise

FPS = 30.0


def _x264(crf: int, pixel_format: str = "yuv444p", **options) -> Encoding:
    return Encoding("libx264", pixel_format, {"crf": str(crf), "preset": "ultrafast", "g": "30", **options})


# (name, writer, container suffix, settings): "cv" = cv2.VideoWriter(api, fourcc), "av" = VideoFileWriter(Encoding)
CANDIDATES = [
    ("OpenCV MJPEG 4:2:0 (AVI)", "cv", ".avi", (cv2.CAP_OPENCV_MJPEG, "MJPG")),
    ("OpenCV FFmpeg MJPEG 4:2:0 (MKV)", "cv", ".mkv", (cv2.CAP_FFMPEG, "MJPG")),
    ("OpenCV FFmpeg MPEG-4 part 2 (MP4)", "cv", ".mp4", (cv2.CAP_FFMPEG, "mp4v")),
    ("OpenCV FFmpeg FFV1 lossless (MKV)", "cv", ".mkv", (cv2.CAP_FFMPEG, "FFV1")),
    ("PyAV x264 4:4:4 CRF 14 (MKV)", "av", ".mkv", _x264(14)),
    ("PyAV x264 4:4:4 CRF 18 tune psnr (MKV)", "av", ".mkv", _x264(18, tune="psnr")),
    # issue 36: the encoder under one core at full HD; cheaper settings of the same encoder, and JPEG in 4:4:4
    ("PyAV x264 4:4:4 CRF 22 tune psnr (MKV)", "av", ".mkv", _x264(22, tune="psnr")),
    ("PyAV x264 4:2:0 CRF 18 tune psnr (MKV)", "av", ".mkv", _x264(18, "yuv420p", tune="psnr")),
    ("PyAV MJPEG 4:4:4 q2 (MKV)", "av", ".mkv", Encoding("mjpeg", "yuvj444p", {"qmin": "2", "qmax": "2"})),
    ("PyAV x264 4:4:4 CRF 20 tune psnr (MKV)", "av", ".mkv", _x264(20, tune="psnr")),
    ("OpenCV JPEG 4:4:4 quality 90 (MKV)", "av", ".mkv", Encoding(OPENCV_JPEG, "yuvj444p", {"quality": "90"})),
    ("OpenCV JPEG 4:4:4 quality 95 (MKV)", "av", ".mkv", Encoding(OPENCV_JPEG, "yuvj444p", {"quality": "95"})),
    ("OpenCV JPEG 4:4:4 luma 75 chroma 93 (MKV)", "av", ".mkv",
     Encoding(OPENCV_JPEG, "yuvj444p", {"quality": "75", "chroma_quality": "93"})),
    ("OpenCV JPEG 4:4:4 luma 75 chroma 95 (MKV)", "av", ".mkv", JPEG_444),
]


def write(kind: str, path: str, settings, frames: list, kill_after: int | None = None) -> float:
    """Write ``frames`` (BGR) to ``path``; returns the CPU seconds spent. ``kill_after``: SIGKILL this process after
    that many frames, nothing closed (run it in a child)."""
    started = time.process_time()
    height, width = frames[0].shape[:2]
    if kind == "cv":
        api, fourcc = settings
        writer = cv2.VideoWriter(path, api, cv2.VideoWriter_fourcc(*fourcc), FPS, (width, height))
        for k, frame in enumerate(frames):
            writer.write(frame)
            _maybe_kill(k, kill_after)
        writer.release()
    else:
        writer = VideoFileWriter(path, width, height, FPS, settings)
        for k, image in enumerate(frames):
            writer.write(image, k)
            _maybe_kill(k, kill_after)
        writer.close()
    return time.process_time() - started


def _maybe_kill(k: int, kill_after: int | None) -> None:
    if kill_after is not None and k + 1 == kill_after:
        import os
        import signal
        os.kill(os.getpid(), signal.SIGKILL)


def decode(path: str) -> list:
    capture = cv2.VideoCapture(path)
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            return frames
        frames.append(frame)


def run(scale: float = 0.5, seed: int = 0, match: str = "", scene: str = "phantom", noise: float = 2.0,
        rounds: int = 1) -> list[dict]:
    """One row per candidate (those whose name contains ``match``, or one of its ``|``-separated texts): node error
    (mm), GB per hour of stereo 1080p30, CPU s per s of stereo video (the median of ``rounds`` writes, the
    candidates taking turns so that each sees the machine's load alike), and the share of frames written before a
    kill that decode afterwards. ``scene``: the still phantom, or the surgery scene's moving camera over tissue;
    ``noise``: the sensor noise (grey levels)."""
    cameras, probe = thesis_calibration().scaled(scale), default_probe_model()
    kind_of_scene = {"phantom": PhantomScene, "surgery": SurgeryScene}[scene]
    tour = kind_of_scene(cameras, probe, Schedule(rest_frames=30, move_frames=5), seed=seed, noise_sigma=noise)
    pairs = [tour.render(k) for k in range(tour.cycle)]
    seconds = len(pairs) / FPS
    tracker = StereoTracker(cameras, probe)
    truth = _nodes(tracker, tour, pairs)
    chosen = [c for c in CANDIDATES if any(text in c[0] for text in match.split("|"))]
    cpu = {name: [] for name, *_ in chosen}
    rows = []
    with tempfile.TemporaryDirectory(prefix="snreg-video-bench-") as folder:
        for turn in range(rounds):
            for n, (name, kind, suffix, settings) in enumerate(chosen):
                paths = [str(Path(folder) / f"{n}.{side}{suffix}") for side in ("left", "right")]
                cpu[name].append(sum(write(kind, p, settings, [pair[side] for pair in pairs])
                                     for side, p in enumerate(paths)))
                if turn == 0:
                    decoded = list(zip(*(decode(p) for p in paths)))
                    size = sum(Path(p).stat().st_size for p in paths)
                    error = (float(np.max(np.linalg.norm(_nodes(tracker, tour, decoded) - truth, axis=1)))
                             if len(decoded) == len(pairs) else float("nan"))
                    rows.append({"name": name, "node_error_mm": round(error, 3),
                                 "gb_per_hour_1080p": round(size / seconds * 3600 / 1e9 / scale ** 2, 1),
                                 "decodable_after_kill": _after_kill(kind, suffix, settings, folder, n)})
    for row in rows:
        row["cpu_s_per_s"] = round(float(np.median(cpu[row["name"]])) / seconds / scale ** 2, 2)
    return rows


def _after_kill(kind: str, suffix: str, settings, folder: str, n: int) -> float:
    """The share of 90 frames written before a SIGKILL that decode: the writer runs in a child process."""
    path = str(Path(folder) / f"kill{n}{suffix}")
    code = ("import numpy as np, sys\nfrom snreg.simulation.video_bench import write\n"
            "from snreg.session.video_writer import Encoding\n"
            f"frames = [np.random.default_rng(k).integers(0, 255, (120, 160, 3), dtype=np.uint8) for k in range(120)]\n"
            f"write({kind!r}, {path!r}, {settings!r}, frames, kill_after=90)\n")
    subprocess.run([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return round(len(decode(path)) / 90, 2) if Path(path).exists() else 0.0


def _nodes(tracker: StereoTracker, scene: PhantomScene, pairs) -> np.ndarray:
    """(4, 3) median tip (camera frame, mm) over each rest's frames."""
    out = []
    for node in range(4):
        tips = []
        for k, pair in enumerate(pairs):
            if scene.resting_node(k) == node:
                try:
                    tips.append(tracker.track(*pair).tip)
                except TrackingError:
                    pass
        out.append(summarise(np.array(tips)).xyz if tips else np.full(3, np.nan))
    return np.array(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snreg.simulation.video_bench", description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=0.5, help="render at this fraction of 1920x1080 (default 0.5)")
    parser.add_argument("--match", default="",
                        help="only the candidates whose name contains this text (or one of several, separated by |)")
    parser.add_argument("--scene", choices=("phantom", "surgery"), default="phantom",
                        help="the still phantom's node tour (default) or the surgery scene's camera moving over tissue")
    parser.add_argument("--noise", type=float, default=2.0, help="sensor noise sigma in grey levels (default 2)")
    parser.add_argument("--rounds", type=int, default=1,
                        help="write each candidate this many times, taking turns, and give the median CPU (default 1)")
    args = parser.parse_args(argv)
    print("| encoder (container) | node error vs originals (max of 4) | stereo 1080p30 per hour | encoder CPU s per s "
          "(1080p, scaled) | frames decodable after kill -9 |\n|---|---|---|---|---|")
    for row in run(args.scale, match=args.match, scene=args.scene, noise=args.noise, rounds=args.rounds):
        print(f"| {row['name']} | {row['node_error_mm']:.2f} mm | {row['gb_per_hour_1080p']:.1f} GB | "
              f"{row['cpu_s_per_s']:.2f} | {row['decodable_after_kill']:.0%} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
