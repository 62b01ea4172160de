"""Gravity's direction in the preop frame (DICOM patient LPS, mm) on the operating table: the registration's start.

Why: the SPECT/CT frame and the trocar frame are unrelated in every real case, but gravity is seen in both. On the
preop side it follows from how the patient lies: DICOM's Patient Position (0018,5100) says it, and the patient lies on
the operating table as on the scanner's (the premise snreg relies on; a patient scanned prone and operated supine
needs the down given by hand). The patient frame is the patient's own (x left, y posterior, z superior, whatever the
image orientation), so a supine patient's down on a level table is posterior (+y) and a prone one's anterior (-y).
The image orientation only matters in that a volume without one (placed by default, :mod:`snreg.preop.volume`) has
no patient frame: its nodes, and so its down, are then unknown in patient terms.

Robot-assisted prostatectomy tilts the table head down (Trendelenburg), so the head goes down and the down gains a
superior (+z) component: ``down = cos(t) level + sin(t) superior`` for a tilt of t degrees. The tilt is set once by
the team and entered by the operator; snreg's default, ``TABLE_TILT_DEG`` = 30, is the steep Trendelenburg usual in
robotic prostatectomy (25-45 degrees are described), so a tilt 15 degrees off the default still lies within the
registration's tilt prior (``down_sd_deg`` 10, tilts searched to 30). A side-lying (decubitus) patient, a position
snreg does not know, or none, gives no down: the operator then gives it by hand.

What the SPECT and the operator said is kept as :class:`PreopDown` (patient position, tilt, whether it was entered),
with the preop nodes: in a node CSV's comments (``snreg preop``) and in the session (``nodes/preop``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from snreg.errors import PreopError

__all__ = ["PreopDown", "TABLE_TILT_DEG", "MAX_TILT_DEG", "SUPERIOR_LPS", "check_tilt", "volume_down"]

TABLE_TILT_DEG = 30.0          # snreg's default head-down tilt: steep Trendelenburg of robotic prostatectomy
MAX_TILT_DEG = 60.0            # beyond any operating table's head-down tilt
SUPERIOR_LPS = np.array([0.0, 0.0, 1.0])
# the patient's down on a level table for the positions a prostatectomy patient can have been scanned in (LPS)
_LEVEL_DOWN = {"HFS": (0.0, 1.0, 0.0), "FFS": (0.0, 1.0, 0.0), "HFP": (0.0, -1.0, 0.0), "FFP": (0.0, -1.0, 0.0)}
_WORDS = {"HFS": "supine, head first", "FFS": "supine, feet first", "HFP": "prone, head first",
          "FFP": "prone, feet first"}
_DECUBITUS = ("HFDR", "HFDL", "FFDR", "FFDL")
_POSITION_KEY, _TILT_KEY = "patient_position", "table_tilt_deg"      # the node CSV's comment keys


def check_tilt(tilt_deg: float) -> float:
    """The table's head-down tilt in degrees, from 0 to ``MAX_TILT_DEG``; PreopError in one sentence otherwise."""
    try:
        tilt = float(tilt_deg)
    except (TypeError, ValueError):
        tilt = float("nan")
    if not 0.0 <= tilt <= MAX_TILT_DEG:          # NaN fails too
        raise PreopError(f"the table tilt must be 0 to {MAX_TILT_DEG:g} degrees head down, got {tilt_deg!r}")
    return tilt


@dataclass(frozen=True)
class PreopDown:
    """What says where down is in the preop frame: the SPECT's Patient Position (its DICOM code, "" when it gives
    none) and the table's head-down tilt in degrees (``tilt_entered``: typed by the operator, else snreg's default).

    :attr:`vector` is the down (unit, LPS) when the position gives one; :attr:`problem` says in words why it does not.
    """

    patient_position: str
    tilt_deg: float = TABLE_TILT_DEG
    tilt_entered: bool = False

    def __post_init__(self):
        object.__setattr__(self, "patient_position", str(self.patient_position).strip().upper())
        object.__setattr__(self, "tilt_deg", check_tilt(self.tilt_deg))

    @property
    def problem(self) -> str:
        """Why the position gives no down ("" when it does): one clause, without what to do."""
        code = self.patient_position
        if code in _LEVEL_DOWN:
            return ""
        if not code:
            return ("the SPECT gives no usable patient position (DICOM Patient Position 0018,5100 and an image "
                    "orientation)")
        if code in _DECUBITUS:
            return (f"the SPECT was taken with the patient on their side (Patient Position {code}), so its down is not "
                    "the operating table's")
        return f"the SPECT's Patient Position {code!r} is none of {', '.join(_LEVEL_DOWN)}"

    @property
    def vector(self) -> np.ndarray:
        """(3,) unit down in LPS: the level down turned head down by the tilt; PreopError with :attr:`problem`."""
        if self.problem:
            raise PreopError(self.problem)
        t = np.radians(self.tilt_deg)
        return np.cos(t) * np.array(_LEVEL_DOWN[self.patient_position]) + np.sin(t) * SUPERIOR_LPS

    @property
    def tilt_words(self) -> str:
        """``"table tilt 30 deg head down (default)"``."""
        return f"table tilt {self.tilt_deg:g} deg head down ({'entered' if self.tilt_entered else 'default'})"

    @property
    def source(self) -> str:
        """Where the down comes from, in words: ``"DICOM HFS (supine, head first), table tilt 30 deg head down
        (default)"``."""
        code = self.patient_position or "without a patient position"
        return f"DICOM {code}{f' ({_WORDS[code]})' if code in _WORDS else ''}, {self.tilt_words}"

    def with_tilt(self, tilt_deg: float) -> "PreopDown":
        """The same position under a tilt the operator entered."""
        return replace(self, tilt_deg=tilt_deg, tilt_entered=True)

    # -- kept with the preop nodes ---------------------------------------------------------------------------
    def comments(self) -> list[str]:
        """Node CSV comment lines (without ``#``): ``patient_position: HFS``, ``table_tilt_deg: 30 (default)``."""
        return [f"{_POSITION_KEY}: {self.patient_position or 'none'}",
                f"{_TILT_KEY}: {self.tilt_deg:g} ({'entered' if self.tilt_entered else 'default'})"]

    @classmethod
    def from_comments(cls, comments, source: str = "node file") -> "PreopDown | None":
        """The record :meth:`comments` wrote among a node file's comments; None when there is none (a file snreg did not
        write from a SPECT); PreopError naming ``source`` when it is unreadable."""
        values = {}
        for comment in comments:
            key, _, value = str(comment).partition(":")
            if key.strip().lower() in (_POSITION_KEY, _TILT_KEY):
                values[key.strip().lower()] = value.strip()
        if _POSITION_KEY not in values:
            return None
        code = values[_POSITION_KEY].split()[0] if values[_POSITION_KEY] else ""
        tilt_text = values.get(_TILT_KEY, f"{TABLE_TILT_DEG:g} (default)")
        try:
            tilt = float(tilt_text.split()[0])
            return cls("" if code.lower() == "none" else code, tilt, "entered" in tilt_text)
        except (ValueError, IndexError, PreopError):
            raise PreopError(f"{source}: the comment '{_TILT_KEY}: {tilt_text}' is not a table tilt of 0 to "
                             f"{MAX_TILT_DEG:g} degrees; correct it or write the file again with snreg preop") from None

    def to_json(self) -> dict:
        return {_POSITION_KEY: self.patient_position, _TILT_KEY: self.tilt_deg, "tilt_entered": self.tilt_entered}

    @classmethod
    def from_json(cls, data: dict) -> "PreopDown":
        return cls(str(data[_POSITION_KEY]), float(data[_TILT_KEY]), bool(data["tilt_entered"]))


def volume_down(volume, tilt_deg: float | None = None) -> PreopDown:
    """What ``volume`` (:class:`~snreg.preop.volume.Volume`) and the operator say about down: its Patient Position
    (none when the volume has no patient frame) and ``tilt_deg`` (None: snreg's default)."""
    position = "" if volume.placed_by_default else volume.patient_position
    if tilt_deg is None:
        return PreopDown(position)
    return PreopDown(position, tilt_deg, tilt_entered=True)
