"""The mouse wheel never changes a value the operator has not clicked into.

Why: scrolling the registration panel over an unfocused spin box changed "max rotation" from 60 to 52 degrees
without notice. One application-wide event filter (installed once, by the main window) gives every spin box,
slider and combo box ``Qt.FocusPolicy.StrongFocus`` (the wheel gives them no focus; set when each is polished,
and at install for those already made) and passes a wheel event over an unfocused one on to its parent, so the
surrounding scroll area scrolls instead. Scroll bars keep their wheel.

>>> install(QApplication.instance())     # idempotent
"""

from __future__ import annotations

from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtGui import QWheelEvent
from PySide6.QtWidgets import QAbstractSlider, QAbstractSpinBox, QApplication, QComboBox, QScrollBar

_GUARDED = (QAbstractSpinBox, QAbstractSlider, QComboBox)


def _guarded(obj) -> bool:
    return isinstance(obj, _GUARDED) and not isinstance(obj, QScrollBar)


class WheelGuard(QObject):
    """The event filter: StrongFocus when a guarded widget is polished; its wheel events only while it has focus."""

    def eventFilter(self, obj, event) -> bool:
        kind = event.type()
        if kind == QEvent.Type.Polish and _guarded(obj):
            obj.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        elif kind == QEvent.Type.Wheel and _guarded(obj) and not obj.hasFocus():
            obj.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
            parent = obj.parentWidget()
            if parent is not None:                      # let the scroll area around it scroll
                QApplication.sendEvent(parent, QWheelEvent(
                    obj.mapTo(parent, event.position()), event.globalPosition(), event.pixelDelta(),
                    event.angleDelta(), event.buttons(), event.modifiers(), event.phase(), event.inverted()))
            return True
        return False


_guard: WheelGuard | None = None


def install(app: QApplication) -> WheelGuard:
    """Install the guard on ``app`` once (widgets polished before it get StrongFocus now); returns it."""
    global _guard
    if _guard is None:
        _guard = WheelGuard(app)
        app.installEventFilter(_guard)
        for widget in app.allWidgets():
            if _guarded(widget):
                widget.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
    return _guard
