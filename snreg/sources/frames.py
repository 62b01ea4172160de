"""The stereo frame-source interface, and the sources that run at a nominal frame rate.

A source hands out :class:`StereoFrame` objects, one per :meth:`FrameSource.read`. It is
``open`` until it has nothing more to give: ``ended`` when a finite source ran out (file
or folder end, renderer done, closed), ``lost`` when it failed (camera unplugged, image
unreadable). Then ``read()`` returns ``None`` and ``problem`` says why in one sentence;
it never raises for that, so a capture loop needs no try/except around it.

Timestamps are nanoseconds: host ``time.perf_counter_ns()`` for live devices, the file
position for video files and a nominal rate (``start_ns + round(index * 1e9 / fps)``) for
image folders and renderers, so replays are deterministic.
"""

from __future__ import annotations

import enum
import glob
import re
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from snreg.errors import SourceError

__all__ = ["StereoFrame", "FrameSource", "SourceState", "SourceError", "CallableSource", "ImageFolderSource",
           "check_bgr"]


class SourceState(enum.Enum):
    OPEN = "open"
    ENDED = "ended"   # a finite source ran out, or was closed
    LOST = "lost"     # the source failed: a device stopped delivering, an image was unreadable


def check_bgr(image, what: str) -> None:
    """Raise ValueError unless ``image`` is an HxWx3 uint8 (BGR) array."""
    if not (isinstance(image, np.ndarray) and image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8):
        got = f"{image.dtype} array of shape {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise ValueError(f"The {what} must be an HxWx3 uint8 BGR array, not a {got}.")


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """One left/right pair: HxWx3 uint8 BGR images and the time (ns) each eye was grabbed."""

    left: np.ndarray
    right: np.ndarray
    t_left_ns: int
    t_right_ns: int
    index: int

    def __post_init__(self):
        check_bgr(self.left, "left image")
        check_bgr(self.right, "right image")

    @property
    def skew_ms(self) -> float:
        """Right-minus-left grab time in milliseconds."""
        return (self.t_right_ns - self.t_left_ns) / 1e6


class FrameSource(ABC):
    """A stream of :class:`StereoFrame`; use as a context manager or call :meth:`close`.

    Read from one thread; ``close()`` belongs to that thread too (OpenCV captures are not
    safe to release while another thread is grabbing).
    """

    def __init__(self, name: str):
        self.name = name
        self._state = SourceState.OPEN
        self._problem = ""
        self._delivered = 0

    @property
    def state(self) -> SourceState:
        return self._state

    @property
    def problem(self) -> str:
        """Why the source is ended or lost, in one sentence; empty while open."""
        return self._problem

    def read(self) -> StereoFrame | None:
        """The next frame, or ``None`` when there is none right now (see ``state``)."""
        if self._state is not SourceState.OPEN:
            return None
        return self._read()

    def close(self) -> None:
        if self._state is SourceState.OPEN:
            self._stop(SourceState.ENDED, f"{self.name} was closed.")
        self._release()

    def __enter__(self) -> "FrameSource":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self) -> Iterator[StereoFrame]:
        """Frames until the source is no longer open (offline replay)."""
        while self._state is SourceState.OPEN:
            frame = self.read()
            if frame is not None:
                yield frame

    @abstractmethod
    def _read(self) -> StereoFrame | None:
        """The next frame of an open source; calls :meth:`_stop` and returns None when there is none."""

    def _release(self) -> None:
        """Free devices and files; may be called more than once."""

    def _stop(self, state: SourceState, problem: str) -> None:
        self._state, self._problem = state, problem
        self._release()

    def _frame(self, left: np.ndarray, right: np.ndarray, t_left_ns: int, t_right_ns: int,
               index: int | None = None) -> StereoFrame:
        """A frame numbered ``index``, by default the count delivered so far."""
        frame = StereoFrame(left, right, int(t_left_ns), int(t_right_ns), self._delivered if index is None else index)
        self._delivered += 1
        return frame


def _check_fps(fps: float) -> float:
    if not fps > 0:
        raise SourceError(f"The frame rate must be a positive number of frames per second, not {fps!r}.")
    return float(fps)


def _nominal_ns(start_ns: int, index: int, fps: float) -> int:
    return start_ns + round(index * 1e9 / fps)


class CallableSource(FrameSource):
    """Frames from ``render(index) -> (left, right)`` at ``fps``; endless when ``n_frames`` is None. Both eyes get the
    same timestamp. This is where the synthetic renderer plugs in.

    Offline (the default) every frame is delivered, stamped at its nominal time from ``start_ns``. ``live``: the
    source behaves as a camera does (docs/design.md, Conventions): frame k is due ``k / fps`` after the first read (or after
    ``epoch_ns`` on the host clock, ``clock``: ``time.perf_counter_ns``, when given: another process showing the same
    scene, the demo's IMU, counts from it too), :meth:`read` waits for the next due frame and, when the consumer has
    fallen behind, skips to the newest one (``index`` jumps over the frames skipped, as the scene went on without
    it). A live frame is stamped with the host time it was grabbed: when it was due, the moment the scene is in the
    state it shows.
    """

    def __init__(self, render: Callable[[int], tuple[np.ndarray, np.ndarray]], fps: float,
                 n_frames: int | None = None, *, start_ns: int = 0, live: bool = False, name: str = "Synthetic source",
                 clock: Callable[[], int] = time.perf_counter_ns, epoch_ns: int | None = None):
        super().__init__(name)
        self._render, self._fps, self._n, self._start = render, _check_fps(fps), n_frames, int(start_ns)
        self._live, self._clock = bool(live), clock
        self._first_ns: int | None = None if epoch_ns is None else int(epoch_ns)
        self._next = 0                  # the index the next read delivers at the earliest

    def _read(self) -> StereoFrame | None:
        if self._live:
            index, t = self._due()
        else:
            index = self._next
            t = _nominal_ns(self._start, index, self._fps)
        if self._n is not None and index >= self._n:
            self._stop(SourceState.ENDED, f"{self.name} rendered all {self._n} frames.")
            return None
        self._next = index + 1
        left, right = self._render(index)
        return self._frame(left, right, t, t, index)

    def _due(self) -> tuple[int, int]:
        """The frame to take now and its grab time: the newest due, after waiting for the next if none is."""
        now = self._clock()
        if self._first_ns is None:
            self._first_ns = now
        due = int((now - self._first_ns) * self._fps // 1e9)
        if due < self._next:
            wait_ns = _nominal_ns(self._first_ns, self._next, self._fps) - now
            time.sleep(max(wait_ns, 0) / 1e9)
            due = self._next
        return due, _nominal_ns(self._first_ns, due, self._fps)


def _natural_key(path: str) -> list:
    """Sort key that orders ``img_2`` before ``img_10``."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path)]


def _matching(pattern: str, eye: str) -> list[str]:
    paths = sorted(glob.glob(str(pattern)), key=_natural_key)
    if not paths:
        raise SourceError(f"No {eye} images match {str(pattern)!r}; check the folder and the pattern.")
    return paths


class ImageFolderSource(FrameSource):
    """Image pairs from two glob patterns, paired in (natural) name order, timestamps at a nominal rate."""

    def __init__(self, left_glob: str, right_glob: str, *, fps: float = 30.0, start_ns: int = 0,
                 name: str | None = None):
        super().__init__(name or f"Image folder {str(left_glob)!r}")
        self._fps, self._start = _check_fps(fps), int(start_ns)
        self._lefts, self._rights = _matching(left_glob, "left"), _matching(right_glob, "right")
        if len(self._lefts) != len(self._rights):
            raise SourceError(f"{len(self._lefts)} left images match {str(left_glob)!r} but {len(self._rights)} "
                              f"right images match {str(right_glob)!r}; every left image needs one right partner.")

    def __len__(self) -> int:
        return len(self._lefts)

    def _read(self) -> StereoFrame | None:
        i = self._delivered
        if i >= len(self._lefts):
            self._stop(SourceState.ENDED, f"All {len(self._lefts)} image pairs of {self.name} were read.")
            return None
        images = []
        for path in (self._lefts[i], self._rights[i]):
            image = cv2.imread(path, cv2.IMREAD_COLOR)
            if image is None:
                self._stop(SourceState.LOST, f"Image {path!r} cannot be read (deleted, or not an image); "
                                             "replace it or remove the pair.")
                return None
            images.append(image)
        t = _nominal_ns(self._start, i, self._fps)
        return self._frame(images[0], images[1], t, t)
