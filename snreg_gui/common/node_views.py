"""Views of two node sets and their pairs: a 3D OpenGL view, or three 2D projections where OpenGL is missing.

Why: the technician must see at a glance whether the preop nodes (mapped into the intraop frame) sit on the
stored intraop nodes, and how far each node's own error reaches (its 90 % ellipsoid). pyqtgraph's OpenGL view needs
PyOpenGL and a working OpenGL context, which remote desktops, virtual machines and offscreen test runs often lack;
:func:`make_node_view` decides at run time and falls back to :class:`~snreg_gui.common.three_view.ThreeViewPlot`
(projections along z, y and x of the trocar frame) rather than ever failing. Both views take a
:class:`~snreg_gui.common.node_scene.NodeScene` through ``show_scene``; items are made once and only updated. Both
show a legend, label each node by its id beside its marker with no label covering another
(:mod:`snreg_gui.common.label_layout`), and fit every node into view, a far one included.

>>> view = make_node_view()            # NodeView3D or ThreeViewPlot; view.kind says which
>>> view.show_scene(NodeScene(mapped_preop_nodes, intraop_nodes, result.pairing))
"""

from __future__ import annotations

import functools

from PySide6.QtGui import QGuiApplication, QOffscreenSurface, QOpenGLContext

from snreg_gui.common.node_scene import MISSING_COLOUR, PREOP_OUT_OF_DATE, NodeScene, legend_html
from snreg_gui.common.node_view_3d import NodeView3D
from snreg_gui.common.three_view import ThreeViewPlot

__all__ = ["NodeScene", "ThreeViewPlot", "NodeView3D", "make_node_view", "opengl_available", "legend_html",
           "MISSING_COLOUR", "PREOP_OUT_OF_DATE"]

_NO_GL_PLATFORMS = ("offscreen", "minimal", "vnc")


@functools.cache
def opengl_available() -> bool:
    """True when pyqtgraph.opengl imports (PyOpenGL) and an OpenGL context can be made current here."""
    if QGuiApplication.instance() is None or QGuiApplication.platformName() in _NO_GL_PLATFORMS:
        return False
    try:
        import pyqtgraph.opengl  # noqa: F401 - needs PyOpenGL, an optional dependency
    except Exception:            # noqa: BLE001 - ImportError, or PyOpenGL failing to find a GL library
        return False
    context = QOpenGLContext()
    if not context.create():
        return False
    surface = QOffscreenSurface()
    surface.setFormat(context.format())
    surface.create()
    if not (surface.isValid() and context.makeCurrent(surface)):
        return False
    context.doneCurrent()
    return True


def make_node_view(parent=None) -> NodeView3D | ThreeViewPlot:
    """The 3D view when OpenGL works here, else the three 2D projections; never raises for lack of OpenGL."""
    if opengl_available():
        try:
            return NodeView3D(parent)
        except Exception:        # noqa: BLE001 - a broken GL stack must cost the 3D view, not the app
            pass
    return ThreeViewPlot(parent)
