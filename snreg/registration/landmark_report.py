"""A registration's landmark pairs in rows and in words, the same on every screen (command line, app, review).

Why: a landmark pair enters the fit as a known correspondence, so a wrong one (a name given to the wrong vessel, a
bifurcation that moved) must never be trusted silently (issue 29). Every screen shows each pair's residual and
leave-one-out residual, names the pairs the registration left out as contradicting the rest
(``landmarks_suspect``), and names the landmarks that took no part because they were given on one side only.

>>> for row in landmark_rows(result): print(row.name, row.residual_mm, row.suspect)
>>> for text in landmark_notes(result, preop.landmarks.ids, intraop.landmarks.ids): print(text)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["LandmarkRow", "landmark_rows", "unpaired_landmarks", "unchecked_note", "landmark_notes"]


@dataclass(frozen=True)
class LandmarkRow:
    """One landmark pair: its residual at the registration, mm; its residual when the nodes and the other pairs alone
    register (NaN when too few points remain); whether it was left out as contradicting the rest."""

    name: str
    residual_mm: float
    leave_one_out_mm: float
    suspect: bool

    def as_json(self) -> dict:
        """For JSON output: NaN as null, mm rounded to 3 decimals."""
        def mm(value: float):
            return None if math.isnan(value) else round(value, 3)
        return {"name": self.name, "residual_mm": mm(self.residual_mm),
                "leave_one_out_mm": mm(self.leave_one_out_mm), "suspect": self.suspect}


def landmark_rows(result) -> list[LandmarkRow]:
    """One :class:`LandmarkRow` per landmark pair of a :class:`~snreg.registration.RegistrationResult`, by name."""
    loo = result.landmark_leave_one_out_mm or {}
    suspects = set(result.landmarks_suspect or ())
    return [LandmarkRow(name, float(mm), float(loo.get(name, math.nan)), name in suspects)
            for name, mm in sorted((result.landmark_residual_mm or {}).items())]


def unpaired_landmarks(preop_names, intraop_names) -> dict[str, list[str]]:
    """The landmark names given on one side only: ``{"preop": [...], "intraop": [...]}``, each sorted."""
    preop, intraop = set(preop_names or ()), set(intraop_names or ())
    return {"preop": sorted(preop - intraop), "intraop": sorted(intraop - preop)}


def unchecked_note(result) -> str | None:
    """The sentence for a registration whose points cannot reveal a wrong landmark (``landmarks_checkable`` False,
    e.g. 1 node and 2 landmarks), saying what to do; None when they can or when no landmark pair took part."""
    if not getattr(result, "landmark_residual_mm", None) or result.landmarks_checkable:
        return None
    pairing = np.asarray(result.pairing)
    points = len(set(pairing[pairing >= 0].tolist())) + len(result.landmark_residual_mm)
    return (f"{points} points in all: a wrong landmark would not show; touch another landmark or store another node "
            "to check them")


def landmark_notes(result, preop_names=(), intraop_names=()) -> list[str]:
    """One sentence per suspect pair, for landmarks the points cannot check (:func:`unchecked_note`), and per landmark
    that took no part, saying what to check."""
    unchecked = unchecked_note(result)
    notes = [unchecked] if unchecked else []
    notes += [f"landmark {row.name!r} contradicts the nodes and the other landmarks ({row.residual_mm:.1f} mm off): "
             "a wrong name, or a vessel that moved; it was left out of the fit, check it on the CT and in surgery"
             for row in landmark_rows(result) if row.suspect]
    unpaired = unpaired_landmarks(preop_names, intraop_names)
    notes += [f"landmark {name!r} is on the CT only: touch it with the probe and store it to use it"
              for name in unpaired["preop"]]
    if unpaired["intraop"] and not set(preop_names or ()):
        stored = ", ".join(map(repr, unpaired["intraop"]))
        notes.append(f"landmark{'s' * (len(unpaired['intraop']) > 1)} {stored} stored in surgery but no CT landmarks "
                     "are loaded: load the CT's landmarks (a 3D Slicer point list, or a node file's landmark rows) "
                     "with the preop nodes to use them")
    else:
        notes += [f"landmark {name!r} was stored in surgery but is not among the CT's landmarks: check its name"
                  for name in unpaired["intraop"]]
    return notes
