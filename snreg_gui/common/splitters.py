"""A splitter's first division: one pane gets the width it asks for, the others share the rest.

Why: a pane's minimum width must stay small, so the window fits a 1024 px screen, but at first show it should
have the width its contents want when there is room (a settings column, a status column). QSplitter divides by size
hints and stretch factors, shrinking every pane alike when the window is narrow; this sets the first division once,
when the splitter is first shown at its real size, and leaves every later drag to the technician.

>>> first_width(splitter, 1, lambda total: max(side.sizeHint().width(), total // 4))
"""

from __future__ import annotations

from collections.abc import Callable

from PySide6.QtCore import QEvent, QObject
from PySide6.QtWidgets import QSplitter


class _FirstWidth(QObject):
    def __init__(self, splitter: QSplitter, index: int, width: Callable[[int], int]):
        super().__init__(splitter)
        self._splitter, self._index, self._width = splitter, index, width

    def eventFilter(self, obj, event) -> bool:                  # noqa: N802 (Qt's name)
        if event.type() in (QEvent.Type.Show, QEvent.Type.Resize) and self._apply():
            obj.removeEventFilter(self)
            self.deleteLater()
        return False

    def _apply(self) -> bool:
        splitter = self._splitter
        total = splitter.width() - splitter.handleWidth() * (splitter.count() - 1)
        if not splitter.isVisible() or total < splitter.minimumSizeHint().width():
            return False
        others = [splitter.widget(k) for k in range(splitter.count()) if k != self._index]
        room = total - sum(w.minimumSizeHint().width() for w in others)
        wanted = max(min(int(self._width(total)), room), splitter.widget(self._index).minimumSizeHint().width())
        share = (total - wanted) // max(len(others), 1)
        sizes = [share] * splitter.count()
        sizes[self._index] = wanted
        splitter.setSizes(sizes)
        return True


def first_width(splitter: QSplitter, index: int, width: Callable[[int], int]) -> None:
    """At its first show, give pane ``index`` of the horizontal ``splitter`` ``width(total)`` px (``total``: the
    panes' width together), but no more than the other panes' minimum widths leave; they share the rest."""
    splitter.installEventFilter(_FirstWidth(splitter, index, width))
