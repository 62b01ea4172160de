"""The video encoder process of :class:`snreg.session.video.StereoRecorder`: ``python -m snreg.session.encoder
SHARED_MEMORY SEGMENT_JSON SESSION_PATH MIN_FREE_BYTES``.

It opens the segment's two files, then reads lines on stdin (``pair SLOT``: encode the pair in that slot of the
shared memory) and answers on stdout (``started``, ``done SLOT WRITTEN FREE_BYTES CPU_S``, ``problem TEXT``,
``closed``). At the end of stdin (the recorder closed it, or the app is gone) it finishes both files and exits.
"""

from __future__ import annotations

import sys
import time
from multiprocessing import resource_tracker, shared_memory
from pathlib import Path

import av
import numpy as np

from snreg.session.video import VideoSegment, free_bytes
from snreg.session.video_writer import VideoFileWriter, recording


def main(argv: list[str]) -> int:
    memory_name, segment_json, session_path, min_free = argv
    import json
    segment = VideoSegment.from_json(json.loads(segment_json))
    memory = shared_memory.SharedMemory(name=memory_name)
    resource_tracker.unregister(memory._name, "shared_memory")     # the recorder owns it and unlinks it
    try:
        encoder = _Encoder(session_path, segment)
    except (av.FFmpegError, OSError, ValueError) as err:
        _say(f"failed {err}")
        memory.close()
        return 1
    _say("started")
    pair_bytes, shape = 2 * segment.width * segment.height * 3, (2, segment.height, segment.width, 3)
    written, problem, checked, free = 0, "", 0.0, -1
    for line in sys.stdin.buffer:
        slot = int(line.split()[1])
        if not problem:
            pair = np.ndarray(shape, np.uint8, memory.buf, slot * pair_bytes)
            try:
                encoder.encode(pair[0], pair[1], written)
                written += 1
            except (av.FFmpegError, OSError, ValueError) as err:
                problem = f"the video could not be written ({err}); recording stopped, the session goes on"
            del pair
            if time.monotonic() - checked > 1.0:          # free space about once a second
                checked, free = time.monotonic(), free_bytes(Path(session_path).parent)
                if free < int(min_free) and not problem:
                    problem = (f"only {free / 1e9:.1f} GB free on the session's disk; video recording stopped, "
                               "the session goes on")
            if problem:
                _say(f"problem {problem}")
        _say(f"done {slot} {written} {free} {time.process_time():.3f}")
    try:
        encoder.close()
    except (av.FFmpegError, OSError, ValueError) as err:
        _say(f"problem the video could not be finished ({err})")
    memory.close()
    _say("closed")
    return 0


def _say(line: str) -> None:
    try:
        sys.stdout.write(line.replace("\n", " ") + "\n")
        sys.stdout.flush()
    except (BrokenPipeError, OSError):
        pass


class _Encoder:
    """The two open files of a segment (in the encoder process), in :func:`~snreg.session.video_writer.recording`'s
    encoding for its size."""

    def __init__(self, session_path: str, segment: VideoSegment):
        self._writers: list[VideoFileWriter] = []
        try:
            for side in range(2):
                self._writers.append(VideoFileWriter(segment.path(session_path, side), segment.width, segment.height,
                                                     segment.fps, recording(segment.width, segment.height)))
        except (av.FFmpegError, OSError, ValueError, KeyError):
            self.close()
            raise

    def encode(self, left: np.ndarray, right: np.ndarray, pts: int) -> None:
        for writer, image in zip(self._writers, (left, right)):
            writer.write(image, pts)

    def close(self) -> None:
        """Close both files (the second also when the first fails; the first failure is raised)."""
        failures = []
        for writer in self._writers:
            try:
                writer.close()
            except (av.FFmpegError, OSError, ValueError) as err:
                failures.append(err)
        if failures:
            raise failures[0]


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
