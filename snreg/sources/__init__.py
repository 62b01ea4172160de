"""Frame sources: cameras, video files and image folders behind one small interface.

Every source yields :class:`StereoFrame` (left/right BGR images with per-eye timestamps)
from ``read()``, and reports ``state`` (open, ended, lost) with a one-sentence ``problem``.
Rendered (simulated) feeds plug in as :class:`CallableSource`; the renderers live in :mod:`snreg.demo`.
"""

from snreg.sources.capture import OpenCVPairSource, OpenCVStackedSource, VideoFilePairSource
from snreg.sources.frames import CallableSource, FrameSource, ImageFolderSource, SourceError, SourceState, StereoFrame

__all__ = ["StereoFrame", "FrameSource", "SourceState", "SourceError", "OpenCVPairSource", "OpenCVStackedSource",
           "VideoFilePairSource", "ImageFolderSource", "CallableSource"]
