"""The mouse wheel never changes a value the operator has not clicked into.

Why: scrolling the registration panel over an unfocused spin box changed "max rotation" from 60 to 52 degrees
without notice. The guard (installed once, by the main window) gives every spin box, slider and combo box
``Qt.FocusPolicy.StrongFocus`` (the wheel gives them no focus; set when each is polished, and at install for those
already made) and passes a wheel event over an unfocused one on to its parent, so the surrounding scroll area scrolls
instead. Scroll bars keep their wheel.

It filters the guarded widgets' events only: an application-wide filter in Python took the interpreter lock for every
event of every widget (paints, timers, queued signals: hundreds a second during acquisition), each time waiting for the
worker threads to let go of it, and the GUI thread stalled (issue 36). New widgets are guarded as the application's
style polishes them (a :class:`~PySide6.QtWidgets.QProxyStyle` of the style in use, whose other methods stay in C++).

>>> install(QApplication.instance())     # idempotent
"""

from __future__ import annotations

from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtGui import QWheelEvent
from PySide6.QtWidgets import (QAbstractSlider, QAbstractSpinBox, QApplication, QComboBox, QProxyStyle, QScrollBar,
                               QWidget)

_GUARDED = (QAbstractSpinBox, QAbstractSlider, QComboBox)


def _guarded(obj) -> bool:
    return isinstance(obj, _GUARDED) and not isinstance(obj, QScrollBar)


class WheelGuard(QObject):
    """The event filter of each guarded widget: its wheel events only while it has focus."""

    def guard(self, widget) -> None:
        """StrongFocus for ``widget`` and its wheel events filtered, when it is one to guard."""
        if _guarded(widget):
            widget.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
            widget.installEventFilter(self)

    def eventFilter(self, obj, event) -> bool:                 # noqa: N802 (Qt's name)
        if event.type() == QEvent.Type.Wheel and _guarded(obj) and not obj.hasFocus():
            obj.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
            parent = obj.parentWidget()
            if parent is not None:                      # let the scroll area around it scroll
                QApplication.sendEvent(parent, QWheelEvent(
                    obj.mapTo(parent, event.position()), event.globalPosition(), event.pixelDelta(),
                    event.angleDelta(), event.buttons(), event.modifiers(), event.phase(), event.inverted()))
            return True
        return False


class _GuardingStyle(QProxyStyle):
    """The application's style as it was, which guards each widget it polishes."""

    def __init__(self, base: str, guard: WheelGuard):
        super().__init__(base)
        self._guard = guard

    def polish(self, *args):
        """Qt's polish (of a widget, a palette or the application) as the base style does it; a widget guarded."""
        if len(args) == 1 and isinstance(args[0], QWidget):
            self._guard.guard(args[0])
        return super().polish(*args)


_guard: WheelGuard | None = None


def install(app: QApplication) -> WheelGuard:
    """Install the guard on ``app`` once (the widgets made before it are guarded now); returns it."""
    global _guard
    if _guard is None:
        _guard = WheelGuard(app)
        for widget in app.allWidgets():
            _guard.guard(widget)
        app.setStyle(_GuardingStyle(app.style().name(), _guard))
    return _guard
