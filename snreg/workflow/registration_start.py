"""Where a registration starts from gravity, for the app's run and ``snreg register`` alike: both downs, where each
came from, and the words that say so.

Why: a technician cannot know the angles between the SPECT/CT and the trocar frame, but the rig knows gravity in both
(:mod:`snreg.preop.gravity`: the SPECT's patient position turned by the table's tilt;
:attr:`snreg.chain.ChainCalibration.down_trocar`: the IMU through the chain's reference). With both,
:func:`~snreg.registration.register` aligns them and searches every heading, so no angle is typed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.errors import PreopError
from snreg.preop.gravity import PreopDown

__all__ = ["GravityStart", "INTRAOP_SOURCE", "gravity_start", "session_gravity"]

INTRAOP_SOURCE = "as the IMU on the endoscope measures it, through the trocar calibration"


@dataclass(frozen=True, eq=False)
class GravityStart:
    """The two downs a registration starts from, (3,) each (preop frame, intraop frame), and where each came from in
    words; ``preop_down`` the patient position and tilt the preop one came from (None when it was given as a vector)."""

    preop: np.ndarray
    intraop: np.ndarray
    preop_source: str
    intraop_source: str = INTRAOP_SOURCE
    preop_down: PreopDown | None = None

    @property
    def down(self) -> tuple[np.ndarray, np.ndarray]:
        """``register``'s ``down``: (down in the preop frame, down in the intraop frame)."""
        return self.preop, self.intraop

    @property
    def words(self) -> str:
        """``"start: gravity, table tilt 30 deg head down (default), heading searched"``."""
        what = self.preop_down.tilt_words if self.preop_down is not None else "the preop down given"
        return f"start: gravity, {what}, heading searched"


def gravity_start(preop_down: PreopDown, intraop_down, intraop_source: str = INTRAOP_SOURCE) -> GravityStart:
    """The start from a patient position and tilt and the intraop down (3,); PreopError with the reason when the
    position gives no down."""
    return GravityStart(preop_down.vector, np.asarray(intraop_down, dtype=float), preop_down.source, intraop_source,
                        preop_down)


def session_gravity(session, preop_down: PreopDown | None = None) -> GravityStart:
    """The start from gravity for the nodes of ``session`` (a :class:`~snreg.session.Session`): the intraop down from
    its chain, the preop down from ``preop_down`` (None: the one stored with its preop nodes). ValueError in one
    sentence saying what is missing (PreopError, SessionError)."""
    preop_down = preop_down or session.preop_down()
    if preop_down is None:
        raise PreopError("the preop nodes carry no patient position, so gravity's direction in their frame is unknown")
    intraop = session.intraop_down()                    # SessionError: no chain, or nodes of another chain
    return gravity_start(preop_down, intraop)
