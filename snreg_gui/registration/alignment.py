"""Manual initial alignment of the preop nodes, as the thesis' MATLAB tool did: three angles and a shift.

Why: every registration method searches only within +-60 degrees / +-60 mm of its initial alignment (thesis
§3.6.2), and preop nodes (patient LPS mm) may start far from the intraop nodes (trocar frame). The technician
turns and shifts the preop set in the view until it roughly covers the intraop set; that rough
``intraop_from_preop`` becomes ``register(..., initial=...)``.

The preop (SPECT, patient LPS) and intraop (trocar) frames are unrelated in every real case, so the alignment starts
from the centroids: the preop centroid ``c`` lands on the intraop centroid ``d``, turned about itself and then
shifted: ``p' = R (p - c) + d + t`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (docs/design.md, Conventions). Untouched (all zero), it
is the centroids matched, so a first Run registers without any manual step; the shift ``t`` is the operator's
correction from there. Without intraop nodes ``d = c``. It is the start only when the operator touches it (``edited``)
or chooses it, or when gravity cannot give one (:mod:`snreg_gui.registration.start`).

>>> box = AlignmentBox()
>>> box.changed.connect(redraw)
>>> initial = box.transform(preop.xyz, intraop.xyz)        # 4x4 intraop_from_preop
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Signal
from PySide6.QtWidgets import QDoubleSpinBox, QGridLayout, QGroupBox, QLabel, QPushButton

from snreg import geometry

ANGLES = (("yaw", "about z", 180.0), ("pitch", "about y", 90.0), ("roll", "about x", 180.0))
MAX_SHIFT_MM = 2000.0


def initial_transform(yaw: float, pitch: float, roll: float, translation_mm, centre_mm, target_mm=None) -> np.ndarray:
    """``intraop_from_preop`` that turns by (yaw, pitch, roll) degrees about ``centre_mm`` and puts it at ``target_mm``
    (``centre_mm`` when None) shifted by ``translation_mm``."""
    rotation = geometry.rotation_from_euler(yaw, pitch, roll)
    centre = np.asarray(centre_mm, dtype=float)
    target = centre if target_mm is None else np.asarray(target_mm, dtype=float)
    return geometry.make_transform(rotation, target + np.asarray(translation_mm, dtype=float) - rotation @ centre)


def _spin(limit: float, suffix: str, step: float) -> QDoubleSpinBox:
    spin = QDoubleSpinBox()
    spin.setRange(-limit, limit)
    spin.setDecimals(1)
    spin.setSingleStep(step)
    spin.setSuffix(suffix)
    spin.setKeyboardTracking(False)
    return spin


class AlignmentBox(QGroupBox):
    """Yaw, pitch, roll (deg) about the preop centroid and x, y, z shift (mm) from the intraop centroid; emits
    ``changed`` on every change, ``edited`` only when the operator changes a value (not :meth:`set_values`)."""

    changed = Signal()
    edited = Signal()

    def __init__(self, parent=None):
        super().__init__("Typed alignment (overrides gravity)", parent)
        self.angle_spins = {}
        for name, _, limit in ANGLES:
            spin = _spin(limit, " deg", 5.0)
            spin.setWrapping(limit == 180.0)
            self.angle_spins[name] = spin
        self.shift_spins = {axis: _spin(MAX_SHIFT_MM, " mm", 5.0) for axis in "xyz"}
        self.reset_button = QPushButton("Reset")
        self.reset_button.setToolTip("back to the centroids matched, no turn")
        grid = QGridLayout(self)
        for row, (name, about, _) in enumerate(ANGLES):
            grid.addWidget(QLabel(f"{name} ({about})"), row, 0)
            grid.addWidget(self.angle_spins[name], row, 1)
            grid.addWidget(QLabel(f"shift {'xyz'[row]}"), row, 2)
            grid.addWidget(self.shift_spins["xyz"[row]], row, 3)
        note = QLabel("starts with the preop centroid on the intraop centroid; turns about it, shifts from there")
        note.setWordWrap(True)
        grid.addWidget(note, 3, 0, 1, 3)
        grid.addWidget(self.reset_button, 3, 3)
        for spin in self._spins():
            spin.valueChanged.connect(self.edited)
            spin.valueChanged.connect(self.changed)
        self.reset_button.clicked.connect(self.reset)

    def _spins(self) -> list[QDoubleSpinBox]:
        return list(self.angle_spins.values()) + list(self.shift_spins.values())

    @property
    def angles_deg(self) -> tuple[float, float, float]:
        return tuple(self.angle_spins[name].value() for name, _, _ in ANGLES)

    @property
    def translation_mm(self) -> np.ndarray:
        return np.array([self.shift_spins[axis].value() for axis in "xyz"])

    def transform(self, preop_xyz, intraop_xyz=None) -> np.ndarray:
        """The initial ``intraop_from_preop`` for these preop nodes (N, 3) mm and intraop nodes (M, 3) mm (None or
        none: the preop centroid stays where it is before the shift)."""
        centre = np.asarray(preop_xyz, dtype=float).reshape(-1, 3).mean(axis=0)
        intraop = None if intraop_xyz is None else np.asarray(intraop_xyz, dtype=float).reshape(-1, 3)
        target = None if intraop is None or not len(intraop) else intraop.mean(axis=0)
        return initial_transform(*self.angles_deg, self.translation_mm, centre, target)

    def set_values(self, angles_deg=(0.0, 0.0, 0.0), translation_mm=(0.0, 0.0, 0.0)) -> None:
        """Set all six values at once; ``changed`` is emitted once."""
        for spin, value in zip(self._spins(), list(angles_deg) + list(translation_mm)):
            spin.blockSignals(True)
            spin.setValue(float(value))
            spin.blockSignals(False)
        self.changed.emit()

    def reset(self) -> None:
        """Back to the centroids matched, without a turn or a shift."""
        self.set_values()
