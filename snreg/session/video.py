"""The stereo video recorded beside a session: two Matroska files, written off the caller's thread.

Why these: tracking the decoded frames must give the nodes within 0.3 mm of tracking the originals, a file cut short
by a kill or a full disk must stay readable up to its last frame, and (issue 36) the encoder must take under a core at
full-HD stereo (docs/guide/review.md, "Recorded video", has the measurements). Full-HD frames (above a megapixel)
are each a JPEG of their own, 4:4:4, brightness at quality 85 and colour at 95 (at brightness 75 the surgery scene's
nodes moved up to 0.43 mm); smaller ones x264 4:4:4 at CRF 18 tuned for PSNR, preset ultrafast, a key frame every
second, as every size was before issue 36 (:func:`~snreg.session.video_writer.recording` chooses, and says why).
Both keep the stripe colours' edges in 4:4:4 (4:2:0 moved the nodes 0.4-1.1 mm) and let a frame leave the encoder at
once; Matroska clusters of at most a quarter second, flushed as written, so a kill loses about the last quarter
second. :mod:`snreg.session.video_writer` writes the files; each segment records its ``codec`` and the readers
decode whatever codec a file holds.

Frame k of each file is row k - ``first_row`` of ``streams/frames`` (0 for a session's first segment), at pts k at the
nominal ``fps``: the true grab times are the rows'. :class:`StereoRecorder` takes pairs on the acquisition thread and
encodes them in its own process; a pair that finds its queue full is counted as ``dropped`` and not written (its
frame row is not written either, so rows and frames stay in step). The encoder takes a second or two to start: the
rows before its first pair have no video (the segment's ``first_row`` is the row of that pair).
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import threading
from dataclasses import dataclass, replace
from multiprocessing import shared_memory
from pathlib import Path

import av
import numpy as np

from snreg.child_process import end_child
from snreg.session.video_writer import CONTAINER, SUFFIX, recording

QUEUE_PAIRS = 12                 # pairs waiting for the encoder (0.4 s at 30 Hz) before one is dropped
RECENT_DROP_PAIRS = 150          # a drop within this many pairs written (5 s at 30 Hz) is news; older ones are history
MIN_FREE_BYTES = 2 * 10**9       # below this free space recording stops (the session goes on)
SIDES = ("left", "right")


@dataclass(frozen=True)
class VideoSegment:
    """One recording of both feeds: files (names beside the session), the frame row its frame 0 is, nominal rate, size.

    ``frames``/``size``/``sha256`` are per side and known once it was closed (``closed``); ``dropped`` pairs the
    encoder could not keep up with; ``stopped``: why recording stopped early ("" when it ran to the end)."""

    n: int
    files: tuple[str, str]
    first_row: int
    fps: float
    width: int
    height: int
    codec: str = ""              # "": the recorder's encoding for this size (video_writer.recording)
    container: str = CONTAINER
    closed: bool = False
    frames: tuple[int, int] = (0, 0)
    size: tuple[int, int] = (0, 0)
    sha256: tuple[str, str] = ("", "")
    dropped: int = 0
    stopped: str = ""

    def __post_init__(self):
        if not self.codec:
            object.__setattr__(self, "codec", recording(self.width, self.height).describe())

    def to_json(self) -> dict:
        return {key: list(value) if isinstance(value, tuple) else value for key, value in self.__dict__.items()}

    @classmethod
    def from_json(cls, data: dict) -> "VideoSegment":
        known = {key: tuple(value) if isinstance(value, list) else value for key, value in data.items()
                 if key in cls.__dataclass_fields__}
        return cls(**known)

    def path(self, session_path: str | Path, side: int) -> Path:
        return Path(session_path).with_name(self.files[side])


def segment_files(session_path: str | Path, n: int) -> tuple[str, str]:
    """The file names of segment ``n`` beside ``session_path``: ``<stem>.left.mkv`` (n = 0), ``<stem>.1.left.mkv``."""
    stem = Path(session_path).stem + ("" if n == 0 else f".{n}")
    return tuple(f"{stem}.{side}{SUFFIX}" for side in SIDES)


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def free_bytes(folder: str | Path) -> int:
    return shutil.disk_usage(folder).free


def count_frames(path: str | Path) -> int:
    """Frames in a recorded file, by its packets (no decoding); a file cut short counts up to its last whole packet."""
    try:
        with av.open(str(path)) as container:
            return sum(1 for packet in container.demux(video=0) if packet.size)
    except (av.FFmpegError, OSError, IndexError):
        return 0


@dataclass
class RecorderState:
    """What the encoder has done, for stream health: pairs written and dropped (and how many were written when the
    last was dropped), pairs waiting, why it stopped, free space on the session's disk (bytes, -1 until measured) and
    the encoder process's CPU time (s)."""

    started: bool = False        # the encoder has opened its files and takes pairs
    written: int = 0
    dropped: int = 0
    written_at_drop: int = 0
    queued: int = 0
    problem: str = ""
    free_bytes: int = -1
    cpu_s: float = 0.0


class StereoRecorder:
    """Encodes the pairs of one :class:`VideoSegment` in a process of its own; :meth:`offer` never blocks.

    Why a process: PyAV holds the GIL between its C calls, and an encoder thread contending with tracking for it
    managed 17 pairs/s instead of 40 (960x540). The pairs travel through ``QUEUE_PAIRS`` slots of shared memory
    (:mod:`snreg.session.encoder` says which slot to encode on its stdin and reports on its stdout); a pair that finds
    no free slot is dropped and counted. The encoder ends when its stdin closes, so it finishes the files even when
    the app is killed; killed itself, it leaves them readable up to the last cluster written.
    """

    def __init__(self, session_path: str | Path, segment: VideoSegment, *, min_free_bytes: int = MIN_FREE_BYTES):
        self.session_path, self.segment = Path(session_path), segment
        self.state = RecorderState()
        self._pair_bytes = 2 * segment.width * segment.height * 3
        self._memory = shared_memory.SharedMemory(create=True, size=QUEUE_PAIRS * self._pair_bytes)
        self._free = list(range(QUEUE_PAIRS))
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._process = subprocess.Popen(
            [sys.executable, "-m", "snreg.session.encoder", self._memory.name, json.dumps(segment.to_json()),
             str(session_path), str(int(min_free_bytes))],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, bufsize=0)
        self._open = True
        threading.Thread(target=self._listen, name="snreg-video-reports", daemon=True).start()

    @property
    def recording(self) -> bool:
        return self._open and not self.state.problem

    @property
    def ready(self) -> bool:
        """The encoder has started (a second or two after the recorder) and takes pairs."""
        return self.state.started and self.recording

    def offer(self, left: np.ndarray, right: np.ndarray) -> bool:
        """Queue a pair (BGR, the segment's size); False when it was not taken: the encoder is behind (counted in
        ``dropped``), not started yet, or recording stopped (``problem`` says why)."""
        if not self.ready:
            return False
        if left.shape != (self.segment.height, self.segment.width, 3) or right.shape != left.shape:
            self.state.problem = (f"the frame size changed to {left.shape[1]}x{left.shape[0]}; recording stopped "
                                  "(a new session records the new size)")
            return False
        with self._lock:
            slot = self._free.pop() if self._free else None
            self.state.queued = QUEUE_PAIRS - len(self._free)
        if slot is None:
            self.state.dropped += 1
            self.state.written_at_drop = self.state.written
            return False
        view = np.ndarray((2, *left.shape), np.uint8, self._memory.buf, slot * self._pair_bytes)
        view[0], view[1] = left, right
        del view
        try:
            self._process.stdin.write(b"pair %d\n" % slot)
        except (BrokenPipeError, OSError, ValueError):
            self.state.problem = self.state.problem or "the video encoder stopped; recording stopped, the session goes on"
            return False
        return True

    def _listen(self) -> None:
        """The encoder's reports (its stdout, one line each): started, done SLOT WRITTEN FREE CPU, problem TEXT, closed."""
        for raw in self._process.stdout:
            kind, _, rest = raw.decode("utf-8", "replace").strip().partition(" ")
            if kind == "started":
                self.state.started = True
            elif kind == "done":
                slot, written, free, cpu = rest.split()
                with self._lock:
                    self._free.append(int(slot))
                    self.state.queued = QUEUE_PAIRS - len(self._free)
                self.state.written, self.state.free_bytes, self.state.cpu_s = int(written), int(free), float(cpu)
            elif kind == "failed" and not self.state.problem:
                self.state.problem = f"the video files {', '.join(self.segment.files)} cannot be written ({rest})"
            elif kind == "problem" and not self.state.problem:
                self.state.problem = rest
            elif kind == "closed":
                break
        if self._open and not self.state.problem:
            self.state.problem = "the video encoder stopped; recording stopped, the session goes on"
        self._closed.set()

    def close(self) -> VideoSegment:
        """Encode what is queued, close both files and return the segment with its frames, sizes and SHA-256."""
        if not self._open:
            return self.segment
        self._open = False
        self._finish_process()
        paths = [self.segment.path(self.session_path, side) for side in range(2)]
        self.segment = replace(self.segment, closed=True, frames=tuple(count_frames(p) for p in paths),
                               size=tuple(p.stat().st_size if p.exists() else 0 for p in paths),
                               sha256=tuple(file_sha256(p) if p.exists() else "" for p in paths),
                               dropped=self.state.dropped, stopped=self.state.problem)
        return self.segment

    def _finish_process(self) -> None:
        """Close the encoder's stdin (it finishes the files and says "closed"), wait for it, free the slots."""
        try:
            self._process.stdin.close()
        except OSError:
            pass
        self._closed.wait(120.0)
        end_child(self._process, 10.0)
        self._memory.close()
        self._memory.unlink()


class VideoReader:
    """Frames of one recorded file by number (BGR); reading on is cheap, a jump seeks to the key frame before it."""

    def __init__(self, path: str | Path, fps: float):
        self.path, self.fps = Path(path), float(fps)
        try:
            self._container = av.open(str(path))
            self._stream = self._container.streams.video[0]
        except (av.FFmpegError, OSError, IndexError) as err:
            raise OSError(f"{path}: not a readable video ({err})") from None
        self._frames = None
        self._next = 0                   # the frame number the decoder gives next

    def _number(self, frame) -> int:
        return int(round(float(frame.pts * self._stream.time_base) * self.fps))

    def read(self, k: int) -> np.ndarray | None:
        """Frame ``k`` as (H, W, 3) uint8 BGR, or None past the end of the file (or where it is damaged)."""
        try:
            if self._frames is None or k < self._next or k > self._next + 2 * round(self.fps):
                target = int(round(k / self.fps / self._stream.time_base))
                self._container.seek(target, stream=self._stream, backward=True, any_frame=False)
                self._frames = self._container.decode(self._stream)
                self._next = -1
            for frame in self._frames:
                number = self._number(frame)
                self._next = number + 1
                if number == k:
                    return frame.to_ndarray(format="bgr24")
                if number > k:
                    break
        except (av.FFmpegError, OSError, ValueError):
            pass
        self._frames = None
        return None

    def close(self) -> None:
        self._container.close()

    def __enter__(self) -> "VideoReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def rows_with_video(session_path: str | Path, segments: list[VideoSegment], n_rows: int) -> np.ndarray:
    """(n_rows,) bool: which ``streams/frames`` rows have a pair in the video (none before a segment's encoder
    started, none after a killed file's last frame)."""
    mask = np.zeros(n_rows, dtype=bool)
    for segment in segments:
        frames = min(segment.frames) if segment.closed else min(count_frames(segment.path(session_path, side))
                                                                   for side in range(2))
        mask[segment.first_row:segment.first_row + frames] = True
    return mask


class RecordedPairs:
    """The left/right pairs of a session's video segments by ``streams/frames`` row (BGR), files opened when first
    needed; OSError when one cannot be opened. One thread at a time."""

    def __init__(self, session_path: str | Path, segments: list[VideoSegment]):
        self._path, self._segments = Path(session_path), segments
        self._open: dict[int, tuple[VideoReader, VideoReader]] = {}

    def pair(self, row: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The pair of frame row ``row``; None when no segment holds it."""
        segment = next((s for s in reversed(self._segments) if row >= s.first_row), None)
        if segment is None:
            return None
        if segment.n not in self._open:
            self._open[segment.n] = tuple(VideoReader(segment.path(self._path, side), segment.fps)
                                          for side in range(2))
        left, right = (reader.read(row - segment.first_row) for reader in self._open[segment.n])
        return None if left is None or right is None else (left, right)

    def close(self) -> None:
        for readers in self._open.values():
            for reader in readers:
                reader.close()
        self._open = {}


def video_text(state, problem: str = "") -> str:
    """The video recording in words, for stream health: frames written, pairs dropped (in capitals, the screen's
    alarm, while the last drop is under :data:`RECENT_DROP_PAIRS` pairs old: the encoder is behind now; "dropped
    earlier" once it keeps up again, so a few pairs lost while it started do not keep the line red all session), free
    space, or why it is not recorded."""
    if state is None:
        return "video: off (turned off in the settings)" if problem == "off" else f"video: not recorded ({problem})"
    free = f", {state.free_bytes / 1e9:.0f} GB free" if state.free_bytes >= 0 else ""
    recent = state.written - state.written_at_drop < RECENT_DROP_PAIRS
    dropped = ("" if not state.dropped else f", {state.dropped} DROPPED (encoder behind)" if recent
               else f", {state.dropped} dropped earlier")
    if state.problem:
        return f"video: STOPPED after {state.written} frames{dropped}: {state.problem}"
    if not state.started:
        return "video: starting the encoder"
    return f"video: recording, {state.written} frames{dropped}{free}"
