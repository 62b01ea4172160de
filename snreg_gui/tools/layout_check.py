"""Cut text and unreachable controls in a shown window: the check the layout tests run at each window size.

Why: a window that reads well at 1920x1080 cut "SPECT folder..." to "SPEC", a table header "label" to "abe" and a
status line's advice to a tooltip at 1024x700 and 1366x768, and a button sat past the window's edge, reachable only by
a horizontal scroll bar. :func:`layout_problems` walks every visible widget of a window and says, in words, each text
that is narrower on screen than its font needs (labels that do not word-wrap, buttons, group box titles, table
headers and cells), each wrapped label lower than its text, each text shown with an ellipsis while its whole text
is only in its tooltip, and each control not wholly inside the window's visible area. A scroll area clips: what it
shows only after scrolling sideways counts as outside; scrolling down a long column is fine.

>>> problems = layout_problems(window)      # [] when every text is whole and every control on screen
"""

from __future__ import annotations

from PySide6.QtCore import QPoint, QRect, Qt
from PySide6 import QtGui
from PySide6.QtGui import QFontMetrics, QTextDocument
from PySide6.QtWidgets import (QAbstractButton, QAbstractItemView, QAbstractScrollArea, QAbstractSpinBox, QCheckBox,
                               QComboBox, QGroupBox, QHeaderView, QLabel, QLineEdit, QPushButton, QRadioButton, QSlider,
                               QStyle, QTableWidget, QWidget)

ELLIPSIS = "\u2026"
SCREEN_SIZES = ((1024, 700), (1366, 768), (1920, 1080))     # issue 35: every screen from 1024x700 up
SLACK_PX = 1                 # rounding between font metrics and layout
CONTROLS = (QAbstractButton, QLineEdit, QComboBox, QAbstractSpinBox, QSlider)


def _name(widget: QWidget) -> str:
    text = ""
    for getter in ("text", "title"):
        if hasattr(widget, getter):
            try:
                text = str(getattr(widget, getter)())
            except TypeError:
                continue
            break
    return f"{type(widget).__name__} {text[:60]!r}" if text else f"{type(widget).__name__} {widget.objectName()!r}"


def visible_rect(widget: QWidget, window: QWidget) -> tuple[QRect, QRect]:
    """(the widget's rect in ``window`` coordinates, the part of it not clipped by an ancestor). A scroll area's
    viewport clips sideways only: what lies below it is reached by scrolling down."""
    own = QRect(widget.mapTo(window, QPoint(0, 0)), widget.size())
    shown, scrolls = QRect(own), False
    parent = widget.parentWidget()
    while parent is not None:
        clip = QRect(parent.mapTo(window, QPoint(0, 0)), parent.size()) if parent is not window else window.rect()
        area = parent.parentWidget()
        scrolls = scrolls or (isinstance(area, QAbstractScrollArea) and area.viewport() is parent
                              and not isinstance(area, QAbstractItemView))
        if scrolls:                                  # scrolled down to, from here up: only sideways clipping counts
            clip = QRect(clip.x(), shown.y(), clip.width(), shown.height())
        shown = shown.intersected(clip)
        if parent is window:
            break
        parent = parent.parentWidget()
    return own, shown


def _text_width(widget: QWidget, text: str) -> int:
    metrics = widget.fontMetrics()
    return max((metrics.horizontalAdvance(line) for line in text.split("\n")), default=0)


def _label_problem(label: QLabel) -> str | None:
    text = label.text()
    if not text or label.pixmap() is not None and not label.pixmap().isNull():
        return None
    if hasattr(label, "needed_lines"):                           # a status line, wrapped when painted
        needed = label.needed_lines()
        return None if needed <= label.shown_lines else f"shows {label.shown_lines} of its {needed} lines"
    width = label.contentsRect().width() - 2 * max(label.margin(), 0) - max(label.indent(), 0)
    if label.textFormat() == Qt.TextFormat.RichText or (label.textFormat() == Qt.TextFormat.AutoText
                                                        and QtGui.Qt.mightBeRichText(text)):
        doc = QTextDocument()
        doc.setDefaultFont(label.font())
        doc.setDocumentMargin(0)
        doc.setHtml(text)
        if label.wordWrap():
            doc.setTextWidth(max(width, 1))
            need_h = doc.size().height()
            return f"needs {need_h:.0f} px high, has {label.contentsRect().height()}" \
                if need_h > label.contentsRect().height() + SLACK_PX + 2 else None
        need = doc.idealWidth()
    elif label.wordWrap():
        need_h = label.heightForWidth(label.width())
        return f"needs {need_h} px high, has {label.height()}" if need_h > label.height() + SLACK_PX else None
    else:
        need = _text_width(label, text)
    return f"needs {need:.0f} px, has {width}" if need > width + SLACK_PX else None


def _button_problem(button: QAbstractButton) -> str | None:
    text = button.text().replace("&&", "\0").replace("&", "").replace("\0", "&")
    if not text:
        return None
    style = button.style()
    need = _text_width(button, text)
    if not button.icon().isNull():
        need += button.iconSize().width() + 4
    if isinstance(button, (QCheckBox, QRadioButton)):
        metric = QStyle.PixelMetric.PM_IndicatorWidth if isinstance(button, QCheckBox) else \
            QStyle.PixelMetric.PM_ExclusiveIndicatorWidth
        need += style.pixelMetric(metric) + style.pixelMetric(QStyle.PixelMetric.PM_CheckBoxLabelSpacing)
    elif isinstance(button, QPushButton):
        need += 2 * style.pixelMetric(QStyle.PixelMetric.PM_DefaultFrameWidth) + 4
        if button.menu() is not None:
            need += style.pixelMetric(QStyle.PixelMetric.PM_MenuButtonIndicator)
    return f"needs {need} px, has {button.width()}" if need > button.width() + SLACK_PX else None


def _table_problems(view: QAbstractItemView) -> list[str]:
    """A header or cell text wider than its column, and columns reached only by the horizontal scroll bar."""
    problems = []
    if not isinstance(view, QTableWidget):
        return problems
    header = view.horizontalHeader()
    if view.horizontalScrollBar().maximum() > 0:
        problems.append(f"{_name(view)}: columns past its right edge (a horizontal scroll bar, "
                        f"{view.horizontalScrollBar().maximum()} steps)")
    padding = 2 * view.style().pixelMetric(QStyle.PixelMetric.PM_HeaderMargin) if header.isVisible() else 0
    for column in range(view.columnCount()):
        if view.isColumnHidden(column):
            continue
        size = header.sectionSize(column)
        item = view.horizontalHeaderItem(column)
        if header.isVisible() and item is not None and item.text():
            need = max(header.fontMetrics().horizontalAdvance(line) for line in item.text().split("\n")) + padding
            if need > size + SLACK_PX:
                problems.append(f"{_name(view)}: header {item.text()!r} needs {need} px, has {size}")
        for row in range(view.rowCount()):
            cell = view.item(row, column)
            if cell is None or not cell.text() or view.isRowHidden(row) or _under_span(view, row, column):
                continue
            width = sum(header.sectionSize(c) for c in range(column, column + view.columnSpan(row, column)))
            problem = _cell_problem(view, cell, width, view.rowHeight(row))
            if problem:
                problems.append(f"{_name(view)}: cell {cell.text()!r} (row {row + 1}) {problem}")
    return problems


def _under_span(view: QTableWidget, row: int, column: int) -> bool:
    """Whether the cell is covered by a span that starts in an earlier column (it is not drawn)."""
    return any(view.columnSpan(row, c) > column - c for c in range(column))


def _cell_problem(view: QTableWidget, cell, width: int, height: int) -> str | None:
    """A cell's text wider than ``width`` px (a word, when the table word-wraps) or, wrapped, higher than its row."""
    metrics = QFontMetrics(cell.font())
    padding = 2 * (view.style().pixelMetric(QStyle.PixelMetric.PM_FocusFrameHMargin, None, view) + 1)   # as Qt's
    room = width - padding
    if not view.wordWrap():
        need = max(metrics.horizontalAdvance(line) for line in cell.text().split("\n"))
        return f"needs {need + padding} px, has {width}" if need > room + SLACK_PX else None
    need = max(metrics.horizontalAdvance(word) for word in cell.text().split())
    if need > room + SLACK_PX:
        return f"has a word of {need + padding} px in {width}"
    high = metrics.boundingRect(QRect(0, 0, room, 10_000), Qt.TextFlag.TextWordWrap, cell.text()).height()
    return f"needs {high} px high, has {height}" if high > height + SLACK_PX else None


def _list_problem(combo: QComboBox) -> str | None:
    """A combo box item wider than the list it drops down (Qt elides it in the middle: "right comm...ifurcation")."""
    texts = [combo.itemText(k) for k in range(combo.count())]
    if not any(texts):
        return None
    view = combo.view()
    padding = 2 * (combo.style().pixelMetric(QStyle.PixelMetric.PM_FocusFrameHMargin, None, view) + 1) + 8
    need = max(view.fontMetrics().horizontalAdvance(text) for text in texts) + padding
    has = max(combo.width(), view.minimumWidth()) - view.verticalScrollBar().sizeHint().width()
    return f"its list needs {need} px, has {has}" if need > has + SLACK_PX else None


def layout_problems(window: QWidget) -> list[str]:
    """Each cut text and each control outside the window's visible area, in words (see the module docstring)."""
    problems = []
    for widget in [window, *window.findChildren(QWidget)]:
        if not widget.isVisible() or widget.window() is not window:
            continue
        own, shown = visible_rect(widget, window)
        where = f"{_name(widget)} at {own.x()},{own.y()} {own.width()}x{own.height()}"
        if shown.isEmpty() and isinstance(widget, QLabel) and widget.text():
            problems.append(f"{where}: not on screen (outside its window or pane)")
            continue
        if shown.isEmpty() and not isinstance(widget, CONTROLS):
            continue                                      # inside a collapsed pane
        if isinstance(widget, CONTROLS) and widget.isVisibleTo(window) and (
                shown.width() < own.width() - SLACK_PX or shown.height() < own.height() - SLACK_PX):
            problems.append(f"{where}: outside the visible window (shows {shown.width()}x{shown.height()})")
        text = ""
        if isinstance(widget, QLabel):
            problem, text = _label_problem(widget), widget.text()
        elif isinstance(widget, QAbstractButton):
            problem, text = _button_problem(widget), widget.text()
        elif isinstance(widget, QComboBox):
            problem = _list_problem(widget)
        elif isinstance(widget, QGroupBox) and widget.title():
            need = _text_width(widget, widget.title()) + 16
            problem = f"title needs {need} px, has {widget.width()}" if need > widget.width() else None
        else:
            problem = None
        if problem:
            problems.append(f"{where}: cut, {problem}")
        tip = widget.toolTip()
        if ELLIPSIS in text and not problem and tip and len(tip) > len(text) and \
                tip.startswith(text.split(ELLIPSIS)[0].rstrip()):
            problems.append(f"{where}: elided, its whole text only in the tooltip")
        if isinstance(widget, QAbstractItemView) and not isinstance(widget, QHeaderView):
            problems.extend(_table_problems(widget))
    return problems


def overlaps(items) -> list[str]:
    """Each pair of ``items`` ((name, QRectF) in one coordinate system, e.g. scene rects of plot labels) that
    overlap, in words."""
    return [f"{a!r} overlaps {b!r}" for k, (a, ra) in enumerate(items) for b, rb in items[k + 1:]
            if ra.intersected(rb).width() > SLACK_PX and ra.intersected(rb).height() > SLACK_PX]
