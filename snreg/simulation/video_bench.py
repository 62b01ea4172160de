"""Which codec and container to record a session's video with: ``python -m snreg.simulation.video_bench [--scale S]``.

Why: the choice (docs/guide/review.md, "Recorded video") rests on four measurements per candidate, on the demo's
rendered phantom tour (sensor noise sigma 2, the worst case for compression; ``--scene surgery`` the camera moving
over tissue, ``--noise`` another sigma): the largest distance between a node tracked on the decoded frames and on
the originals (median of each rest's fixes; ``--seed 0-5`` several scenes, the largest over all; beside it how far
the tip moves per fix, and fixes won or lost), the size of an hour of stereo 1080p30 (measured at ``scale`` of 1080p
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
from snreg.session.video_writer import OPENCV_JPEG, Encoding, VideoFileWriter
from snreg.tracking import StereoTracker, TrackingError, summarise

FPS = 30.0


def _x264(crf: int, pixel_format: str = "yuv444p", **options) -> Encoding:
    return Encoding("libx264", pixel_format, {"crf": str(crf), "preset": "ultrafast", "g": "30", **options})


def _jpeg(luma: int, chroma: int) -> Encoding:
    return Encoding(OPENCV_JPEG, "yuvj444p", {"quality": str(luma), "chroma_quality": str(chroma)})


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
    ("OpenCV JPEG 4:4:4 luma 75 chroma 93 (MKV)", "av", ".mkv", _jpeg(75, 93)),
    ("OpenCV JPEG 4:4:4 luma 75 chroma 95 (MKV)", "av", ".mkv", _jpeg(75, 95)),
    # issue 36, second attempt: higher brightness or colour quality (quality 95 above is luma 95 chroma 95)
    ("OpenCV JPEG 4:4:4 luma 75 chroma 97 (MKV)", "av", ".mkv", _jpeg(75, 97)),
    ("OpenCV JPEG 4:4:4 luma 75 chroma 98 (MKV)", "av", ".mkv", _jpeg(75, 98)),
    ("OpenCV JPEG 4:4:4 luma 85 chroma 95 (MKV)", "av", ".mkv", _jpeg(85, 95)),
    ("OpenCV JPEG 4:4:4 luma 90 chroma 95 (MKV)", "av", ".mkv", _jpeg(90, 95)),
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


def run(scale: float = 0.5, seed: int | tuple[int, ...] = 0, match: str = "", scene: str = "phantom",
        noise: float = 2.0, rounds: int = 1, rests_only: bool = False) -> list[dict]:
    """One row per candidate (those whose name contains ``match``, or one of its ``|``-separated texts): node error
    (mm; the largest of every node of every ``seed``, and each seed's), the tracked tip's move per fix (median and 95th
    percentile over the rests' fixes both tracked), fixes won or lost by decoding, GB per hour of stereo 1080p30, CPU
    s per s of stereo video (the median of ``rounds`` writes per seed, the candidates taking turns so that each sees
    the machine's load alike), and the share of frames written before a kill that decode afterwards. ``scene``: the
    still phantom, or the surgery scene's moving camera over tissue; ``noise``: the sensor noise (grey levels);
    ``rests_only``: write only the rests' frames (all the node measure uses; the surgery tour's moving frames cost
    seconds each to render at full HD), which for x264 also changes what its inter frames predict from."""
    seeds = (seed,) if isinstance(seed, int) else tuple(seed)
    chosen = [c for c in CANDIDATES if any(text in c[0] for text in match.split("|"))]
    found = {name: {"errors": [], "moves": [], "won_lost": [0, 0], "bytes": [], "cpu": []} for name, *_ in chosen}
    seconds = 0.0
    for one in seeds:
        seconds += _one_seed(scale, one, chosen, scene, noise, rounds, rests_only, found)
    rows = []
    for n, (name, kind, suffix, settings) in enumerate(chosen):
        got = found[name]
        moves = np.concatenate(got["moves"])
        with tempfile.TemporaryDirectory(prefix="snreg-video-bench-") as folder:
            after_kill = _after_kill(kind, suffix, settings, folder, n)
        rows.append({"name": name, "node_error_mm": round(max(got["errors"]), 3),
                     "node_error_by_seed_mm": [round(e, 2) for e in got["errors"]],
                     "fix_move_median_mm": round(float(np.median(moves)), 3),
                     "fix_move_p95_mm": round(float(np.percentile(moves, 95)), 3),
                     "fixes_won": got["won_lost"][0], "fixes_lost": got["won_lost"][1],
                     "gb_per_hour_1080p": round(sum(got["bytes"]) / seconds * 3600 / 1e9 / scale ** 2, 1),
                     "cpu_s_per_s": round(float(np.median(got["cpu"])) / scale ** 2, 2),
                     "decodable_after_kill": after_kill})
    return rows


def _one_seed(scale, seed, chosen, scene, noise, rounds, rests_only, found) -> float:
    """Render one seed's tour, write and decode it with each chosen candidate into ``found``; its seconds of video."""
    cameras, probe = thesis_calibration().scaled(scale), default_probe_model()
    kind_of_scene = {"phantom": PhantomScene, "surgery": SurgeryScene}[scene]
    tour = kind_of_scene(cameras, probe, Schedule(rest_frames=30, move_frames=5), seed=seed, noise_sigma=noise)
    frames = [k for k in range(tour.cycle) if not rests_only or tour.resting_node(k) is not None]
    pairs, node_of = [tour.render(k) for k in frames], [tour.resting_node(k) for k in frames]
    seconds = len(pairs) / FPS
    tracker = StereoTracker(cameras, probe)
    truth = fixes(tracker, pairs, node_of)
    with tempfile.TemporaryDirectory(prefix="snreg-video-bench-") as folder:
        for turn in range(rounds):
            for n, (name, kind, suffix, settings) in enumerate(chosen):
                paths = [str(Path(folder) / f"{n}.{side}{suffix}") for side in ("left", "right")]
                cpu = sum(write(kind, p, settings, [pair[side] for pair in pairs]) for side, p in enumerate(paths))
                found[name]["cpu"].append(cpu / seconds)
                if turn == 0:
                    _compare(tracker, [str(p) for p in paths], truth, pairs, node_of, found[name])
    return seconds


def _compare(tracker, paths, truth, pairs, node_of, got: dict) -> None:
    """Track the decoded files' rests against ``truth`` (the originals' fixes) into ``got``."""
    decoded = list(zip(*(decode(p) for p in paths)))
    got["bytes"].append(sum(Path(p).stat().st_size for p in paths))
    if len(decoded) != len(pairs):
        got["errors"].append(float("nan"))
        got["moves"].append(np.array([np.nan]))
        return
    after = fixes(tracker, decoded, node_of)
    got["errors"].append(float(np.max(np.linalg.norm(nodes_of(after, node_of) - nodes_of(truth, node_of), axis=1))))
    both = np.isfinite(truth[:, 0]) & np.isfinite(after[:, 0])
    got["moves"].append(np.linalg.norm(after[both] - truth[both], axis=1))
    got["won_lost"][0] += int(np.sum(np.isnan(truth[:, 0]) & np.isfinite(after[:, 0])))
    got["won_lost"][1] += int(np.sum(np.isfinite(truth[:, 0]) & np.isnan(after[:, 0])))


def _after_kill(kind: str, suffix: str, settings, folder: str, n: int) -> float:
    """The share of 90 frames written before a SIGKILL that decode: the writer runs in a child process."""
    path = str(Path(folder) / f"kill{n}{suffix}")
    code = ("import numpy as np, sys\nfrom snreg.simulation.video_bench import write\n"
            "from snreg.session.video_writer import Encoding\n"
            f"frames = [np.random.default_rng(k).integers(0, 255, (120, 160, 3), dtype=np.uint8) for k in range(120)]\n"
            f"write({kind!r}, {path!r}, {settings!r}, frames, kill_after=90)\n")
    subprocess.run([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return round(len(decode(path)) / 90, 2) if Path(path).exists() else 0.0


def fixes(tracker: StereoTracker, pairs, node_of) -> np.ndarray:
    """(n, 3) the tip tracked in each pair resting on a node (``node_of[k]`` not None; camera frame, mm), NaN where
    there is no fix or no rest."""
    out = np.full((len(pairs), 3), np.nan)
    for k, pair in enumerate(pairs):
        if node_of[k] is not None:
            try:
                out[k] = tracker.track(*pair).tip
            except TrackingError:
                pass
    return out


def nodes_of(tips: np.ndarray, node_of) -> np.ndarray:
    """(4, 3) each node's median fix (:func:`~snreg.tracking.summarise`), NaN for a node without one."""
    out = []
    for node in range(4):
        mine = tips[[k for k, n in enumerate(node_of) if n == node]]
        mine = mine[np.isfinite(mine[:, 0])]
        out.append(summarise(mine).xyz if len(mine) else np.full(3, np.nan))
    return np.array(out)


def _nodes(tracker: StereoTracker, scene: PhantomScene, pairs) -> np.ndarray:
    """(4, 3) median tip (camera frame, mm) over each rest's frames, pair k being the scene's frame k."""
    node_of = [scene.resting_node(k) for k in range(len(pairs))]
    return nodes_of(fixes(tracker, pairs, node_of), node_of)


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
    parser.add_argument("--seed", type=_seeds, default=(0,),
                        help="the scene's seed, or several (0,1,2 or 0-5): the node error is the largest (default 0)")
    parser.add_argument("--rests-only", action="store_true",
                        help="write only the frames resting on a node (the surgery tour's moves are slow to render)")
    args = parser.parse_args(argv)
    print("| encoder (container) | node error vs originals (max of 4; per seed) | tip move per fix, median / p95 | "
          "fixes won / lost | stereo 1080p30 per hour | encoder CPU s per s (1080p, scaled) | "
          "frames decodable after kill -9 |\n|---|---|---|---|---|---|---|")
    for row in run(args.scale, args.seed, args.match, args.scene, args.noise, args.rounds, args.rests_only):
        by_seed = " ".join(f"{e:.2f}" for e in row["node_error_by_seed_mm"])
        print(f"| {row['name']} | {row['node_error_mm']:.2f} mm ({by_seed}) | {row['fix_move_median_mm']:.2f} / "
              f"{row['fix_move_p95_mm']:.2f} mm | {row['fixes_won']} / {row['fixes_lost']} | "
              f"{row['gb_per_hour_1080p']:.1f} GB | {row['cpu_s_per_s']:.2f} | {row['decodable_after_kill']:.0%} |",
              flush=True)
    return 0


def _seeds(text: str) -> tuple[int, ...]:
    """``0``, ``0,2,5`` or ``0-5`` as seeds."""
    try:
        out = []
        for part in text.split(","):
            first, _, last = part.partition("-")
            out += range(int(first), int(last or first) + 1)
        return tuple(out)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seeds are numbers like 0, 0,2,5 or 0-5, not {text!r}") from None


if __name__ == "__main__":
    sys.exit(main())
