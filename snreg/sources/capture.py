"""OpenCV capture sources: two devices, one side-by-side/top-bottom device, a pair of video files.

All three run the same code after their ``cv2.VideoCapture`` objects (:class:`_CaptureSource`):
grab every capture first, then retrieve every capture, so the eyes are latched as close
together in time as the driver allows and decoding happens afterwards. A camera and a
video file differ only in two settings: where the timestamp comes from (host
``perf_counter_ns()`` at grab, or the file position ``CAP_PROP_POS_MSEC`` for
deterministic replay) and what a failed grab means (the camera is lost, the file ended).
A device may also be a path or URL, so tests drive the device code with video files.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from snreg.sources.frames import FrameSource, SourceError, SourceState, StereoFrame

__all__ = ["OpenCVPairSource", "OpenCVStackedSource", "VideoFilePairSource", "LAYOUTS"]

Device = int | str | os.PathLike
LAYOUTS = ("side_by_side", "top_bottom")
_Split = Callable[[list[np.ndarray]], tuple[np.ndarray, np.ndarray]]


def _device_label(device: Device) -> str:
    return f"camera {device}" if isinstance(device, int) else f"camera {str(device)!r}"


def _capitalized(text: str) -> str:
    return text[:1].upper() + text[1:]


def _open_device(device: Device, backend: int, frame_size: tuple[int, int] | None) -> cv2.VideoCapture:
    """An opened capture of a camera index, device path or URL, at ``frame_size`` (width, height) if given."""
    capture = cv2.VideoCapture(device if isinstance(device, int) else str(device), backend)
    if not capture.isOpened():
        raise SourceError(f"Cannot open {_device_label(device)}: check that it is connected and not in use by "
                          "another program, or choose another device index or path.")
    if frame_size is not None:
        width, height = (int(v) for v in frame_size)
        capture.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        capture.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        got = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        if got != (width, height):
            capture.release()
            raise SourceError(f"{_capitalized(_device_label(device))} delivers {got[0]}x{got[1]} frames, not the "
                              f"requested {width}x{height}; choose a size the camera supports.")
    return capture


def _open_file(path: str | os.PathLike, backend: int) -> cv2.VideoCapture:
    if not Path(path).is_file():
        raise SourceError(f"Video file {str(path)!r} does not exist; check the path.")
    capture = cv2.VideoCapture(str(path), backend)
    if not capture.isOpened():
        raise SourceError(f"Cannot decode video file {str(path)!r}; convert it to a format OpenCV reads "
                          "(for example MJPG in .avi, or H.264 in .mp4).")
    return capture


def _open_all(opener: Callable[[object], cv2.VideoCapture], targets: Sequence) -> list[cv2.VideoCapture]:
    """Open every target, releasing the ones already open when a later one fails."""
    captures: list[cv2.VideoCapture] = []
    try:
        for target in targets:
            captures.append(opener(target))
    except SourceError:
        for capture in captures:
            capture.release()
        raise
    return captures


class _CaptureSource(FrameSource):
    """The shared code path after the captures: grab all, retrieve all, split into eyes, timestamp.

    ``live`` sources stamp host time at each grab and become ``lost`` after more than
    ``tolerated_failures`` failed reads in a row (each returns None meanwhile); file
    sources stamp the file position and become ``ended`` at the first failed read.
    """

    def __init__(self, captures: list[cv2.VideoCapture], labels: list[str], split: _Split, *, name: str,
                 live: bool, tolerated_failures: int = 0):
        super().__init__(name)
        self._captures, self._labels, self._split = captures, labels, split
        self._live, self._tolerated = live, int(tolerated_failures)
        self._failures = 0

    def _read(self) -> StereoFrame | None:
        stamps = []
        for k, capture in enumerate(self._captures):
            if not self._safely(capture.grab):
                return self._failed(k)
            stamps.append(time.perf_counter_ns() if self._live
                          else round(capture.get(cv2.CAP_PROP_POS_MSEC) * 1e6))
        images = []
        for k, capture in enumerate(self._captures):
            ok, image = self._safely(capture.retrieve) or (False, None)
            if not ok or image is None:
                return self._failed(k)
            images.append(image)
        self._failures = 0
        left, right = self._split(images)
        return self._frame(left, right, stamps[0], stamps[-1])

    @staticmethod
    def _safely(call):
        """``call()``, with an OpenCV error (seen from some drivers on unplug) read as a failure."""
        try:
            return call()
        except cv2.error:
            return None

    def _failed(self, k: int) -> None:
        self._failures += 1
        label, n = self._labels[k], self._delivered
        if not self._live:
            self._stop(SourceState.ENDED, f"{label} ended after {n} frames.")
        elif self._failures > self._tolerated:
            self._stop(SourceState.LOST, f"{_capitalized(label)} stopped delivering frames after {n} frames "
                                         "(unplugged, switched off or taken by another program?); reconnect it "
                                         "and open the source again.")
        return None

    def _release(self) -> None:
        for capture in self._captures:
            capture.release()


def _pair(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    return images[0], images[1]


def _stacked_split(layout: str) -> _Split:
    if layout not in LAYOUTS:
        raise SourceError(f"Unknown stereo layout {layout!r}; use one of {', '.join(LAYOUTS)}.")
    axis = 1 if layout == "side_by_side" else 0

    def split(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        (image,) = images
        half = image.shape[axis] // 2
        first, second = (image[:, :half], image[:, half:2 * half]) if axis else (image[:half], image[half:2 * half])
        return np.ascontiguousarray(first), np.ascontiguousarray(second)
    return split


class OpenCVPairSource(_CaptureSource):
    """Two capture devices (index, device path or URL), one per eye; host timestamps at grab."""

    def __init__(self, left_device: Device, right_device: Device, *, backend: int = cv2.CAP_ANY,
                 frame_size: tuple[int, int] | None = None, tolerated_failures: int = 2, name: str | None = None):
        captures = _open_all(lambda d: _open_device(d, backend, frame_size), (left_device, right_device))
        labels = [f"left {_device_label(left_device)}", f"right {_device_label(right_device)}"]
        super().__init__(captures, labels, _pair, name=name or f"Cameras {left_device}/{right_device}", live=True,
                         tolerated_failures=tolerated_failures)


class OpenCVStackedSource(_CaptureSource):
    """One capture device delivering both eyes in one frame, left eye first (left half, or top half)."""

    def __init__(self, device: Device, layout: str = "side_by_side", *, backend: int = cv2.CAP_ANY,
                 frame_size: tuple[int, int] | None = None, tolerated_failures: int = 2, name: str | None = None):
        split = _stacked_split(layout)
        captures = _open_all(lambda d: _open_device(d, backend, frame_size), (device,))
        super().__init__(captures, [_device_label(device)], split, name=name or f"Stacked camera {device}",
                         live=True, tolerated_failures=tolerated_failures)


class VideoFilePairSource(_CaptureSource):
    """A left and a right video file; timestamps are the file positions, so a replay is deterministic."""

    def __init__(self, left_path: str | os.PathLike, right_path: str | os.PathLike, *, backend: int = cv2.CAP_ANY,
                 name: str | None = None):
        captures = _open_all(lambda p: _open_file(p, backend), (left_path, right_path))
        labels = [f"Left video file {str(left_path)!r}", f"Right video file {str(right_path)!r}"]
        super().__init__(captures, labels, _pair, name=name or f"Video files {Path(left_path).name}/"
                         f"{Path(right_path).name}", live=False)
