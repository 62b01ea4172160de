"""Writing one recorded video file: how it is encoded (:class:`Encoding`) and the writer (:class:`VideoFileWriter`).

Why here: the recorder's encoder process (:mod:`snreg.session.encoder`) and the codec study
(:mod:`snreg.simulation.video_bench`) write files the same way, so what the study measures is what the recorder does.
The recording's encoding depends on the frame size (:func:`recording`; docs/guide/review.md, "Recorded video").
Above a megapixel per eye (full HD), since issue 36, :data:`JPEG_444`: each frame a 4:4:4 JPEG from OpenCV's
libjpeg-turbo (brightness at quality 85, colour at 95) muxed as Matroska MJPEG, about 0.8 CPU s per s of full-HD
stereo where x264 4:4:4 CRF 18 (:data:`X264_444`) took about 2, at about five times x264's disk (65-73 GB per hour).
The tracker finds the stripes by colour thresholds; compression moves a few of a stripe's edge pixels across them,
which shifts its centroid by hundredths of a pixel and the tip's depth by tenths of a millimetre: at brightness
quality 75 a node moved 0.3-0.4 mm on the surgery scene at full HD; at 85, over six seeds, at most 0.15 mm. Smaller
frames keep x264: it takes under a core there (its CPU goes with the pixels), and JPEG's 8x8 blocks are coarse
against smaller stripes (0.5-0.9 mm at 480x270; at the demo's 960x540, on the surgery scene's six seeds, up to 1.1 mm
at luma 85 where x264 moved a node 0.33 mm: docs/guide/review.md). The readers decode whatever codec a file holds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

CONTAINER, SUFFIX = "matroska", ".mkv"
CONTAINER_OPTIONS = {"cluster_time_limit": "250", "cluster_size_limit": "4000000", "flush_packets": "1"}
OPENCV_JPEG = "opencv-jpeg"      # Encoding.codec: JPEG from OpenCV (libjpeg-turbo), muxed as FFmpeg's "mjpeg"
ENCODER_THREADS = 2              # x264's threads per eye (its frame threads delay output by about as many frames)


@dataclass(frozen=True)
class Encoding:
    """How frames become a file's packets: ``codec`` an FFmpeg encoder through PyAV (``options`` its AVOptions,
    ``pixel_format`` what it encodes), or :data:`OPENCV_JPEG` (``options["quality"]`` 1-100, ``"chroma_quality"``
    the colour planes' when it differs; ``pixel_format`` ``yuvj444p``, full-range 4:4:4 as JPEG has it)."""

    codec: str
    pixel_format: str
    options: dict = field(default_factory=dict)

    def describe(self) -> str:
        """What a session records as a segment's ``codec``, e.g. ``mjpeg yuvj444p quality 75 chroma 95
        (libjpeg-turbo)``."""
        if self.codec == OPENCV_JPEG:
            chroma = f" chroma {self.options['chroma_quality']}" if "chroma_quality" in self.options else ""
            return f"mjpeg {self.pixel_format} quality {self.options['quality']}{chroma} (libjpeg-turbo)"
        shown = " ".join(f"{key} {value}" for key, value in self.options.items() if key in ("crf", "tune", "q", "qmin"))
        return f"{self.codec} {self.pixel_format} {shown}".strip()


JPEG_444 = Encoding(OPENCV_JPEG, "yuvj444p", {"quality": "85", "chroma_quality": "95"})
X264_444 = Encoding("libx264", "yuv444p", {"crf": "18", "tune": "psnr", "preset": "ultrafast", "g": "30"})
JPEG_ABOVE_PIXELS = 1_000_000    # per eye: x264 at about 1 CPU s per s of stereo per megapixel takes a core here


def recording(width: int, height: int) -> Encoding:
    """What the recorder writes frames of ``width`` x ``height`` in: :data:`JPEG_444` above
    :data:`JPEG_ABOVE_PIXELS` (full HD), :data:`X264_444` below (see the module's docstring). Before issue 36 every
    size was recorded in x264."""
    return JPEG_444 if width * height > JPEG_ABOVE_PIXELS else X264_444


class VideoFileWriter:
    """One Matroska file of BGR frames at ``fps`` in ``encoding``; :meth:`write` frame k at pts k, :meth:`close`.

    A frame is written (its packets muxed, the cluster flushed at its time limit) before :meth:`write` returns,
    except an FFmpeg encoder's own delay (x264's frame threads: a frame or two)."""

    def __init__(self, path: str | Path, width: int, height: int, fps: float, encoding: Encoding,
                 threads: int = ENCODER_THREADS):
        self.encoding = encoding
        self._container = av.open(str(path), "w", format=CONTAINER, container_options=CONTAINER_OPTIONS)
        try:
            rate = Fraction(fps).limit_denominator(1001)
            self._jpeg = encoding.codec == OPENCV_JPEG
            self._stream = self._container.add_stream("mjpeg" if self._jpeg else encoding.codec, rate=rate,
                                                      options={} if self._jpeg else encoding.options)
            self._stream.width, self._stream.height, self._stream.pix_fmt = width, height, encoding.pixel_format
            if self._jpeg:
                self._time_base = 1 / rate
                if encoding.pixel_format != "yuvj444p":
                    raise ValueError(f"OpenCV's JPEG is written in yuvj444p here, not {encoding.pixel_format}")
                self._params = [cv2.IMWRITE_JPEG_QUALITY, int(encoding.options["quality"]),
                                cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]
                if "chroma_quality" in encoding.options:
                    self._params += [cv2.IMWRITE_JPEG_LUMA_QUALITY, int(encoding.options["quality"]),
                                     cv2.IMWRITE_JPEG_CHROMA_QUALITY, int(encoding.options["chroma_quality"])]
            else:
                self._stream.thread_count = threads
        except (KeyError, ValueError, av.FFmpegError):
            self._container.close()
            raise

    def write(self, image: np.ndarray, pts: int) -> None:
        """Encode ``image`` ((H, W, 3) uint8 BGR, the file's size) as frame ``pts``."""
        if self._jpeg:
            ok, data = cv2.imencode(".jpg", image, self._params)
            if not ok:
                raise ValueError("OpenCV could not encode the frame as JPEG")
            packet = av.Packet(data.tobytes())
            packet.stream, packet.time_base, packet.pts, packet.dts = self._stream, self._time_base, pts, pts
            packet.is_keyframe = True
            self._container.mux(packet)
            return
        frame = av.VideoFrame.from_ndarray(image, format="bgr24")
        frame.pts = pts
        for packet in self._stream.encode(frame):
            self._container.mux(packet)

    def close(self) -> None:
        """Flush the encoder and close the file (also after a failed write)."""
        try:
            if not self._jpeg:
                for packet in self._stream.encode():
                    self._container.mux(packet)
        finally:
            self._container.close()
