"""Frame sources: cameras, video files, image folders and renderers behind one small interface.

Every source yields :class:`StereoFrame` (left/right BGR images with per-eye timestamps)
from ``read()``, and reports ``state`` (open, ended, lost) with a one-sentence ``problem``.
"""

from snreg.sources.capture import OpenCVPairSource, OpenCVStackedSource, VideoFilePairSource
from snreg.sources.frames import CallableSource, FrameSource, ImageFolderSource, SourceError, SourceState, StereoFrame
from snreg.sources.synthetic import ProbePose, RenderOptions, StereoRenderer

__all__ = ["StereoFrame", "FrameSource", "SourceState", "SourceError", "OpenCVPairSource", "OpenCVStackedSource",
           "VideoFilePairSource", "ImageFolderSource", "CallableSource", "StereoRenderer", "ProbePose", "RenderOptions"]
