"""The exceptions a user can cause: each carries one sentence saying what is wrong and what to do.

Why one module: the command line turns every one of them into one line on stderr and exit status 2,
the app into one line in its status bar, so they are defined once, below everything that raises them.
All but :class:`UserError` are ``ValueError``s, so code that validates input may catch that alone.
"""

from __future__ import annotations

__all__ = ["UserError", "NodeFileError", "CalibrationFileError", "SourceError", "ImuPortError", "PreopError",
           "SessionError", "TrackingError", "StoreError", "NoFitError", "TooFewPairsError", "LiveLinkError",
           "StoreRefused", "StoreNeedsConfirmation"]


class UserError(Exception):
    """Bad input on the command line: reported as one line on stderr with exit status 2."""


class NodeFileError(ValueError):
    """A node file that cannot be read; the message says which file and what to fix."""


class CalibrationFileError(ValueError):
    """A calibration file that cannot be used; the message says which file and why."""


class SourceError(ValueError):
    """A frame source that cannot be opened or configured; the message says what to do."""


class ImuPortError(ValueError):
    """The IMU port cannot be opened; the message says what to do."""


class PreopError(ValueError):
    """Input that cannot become a preop volume or node set; one sentence a user can act on."""


class SessionError(ValueError):
    """A session file that cannot be used; the message is one sentence naming the file and what to do."""


class TrackingError(ValueError):
    """No usable probe position in this stereo pair; the message says why."""


class StoreError(ValueError):
    """A node that cannot be stored now; the message says what to do."""


class NoFitError(ValueError):
    """No pairing of the node sets fits within the registration's bounds; the message names what to change."""


class TooFewPairsError(ValueError):
    """Fewer nodes can pair than a registration needs, though each side has enough: the left/right labels let fewer
    than three stored nodes pair with a hot spot of their side (say three left nodes stored, two left hot spots). The
    message says what to store or check; the app may simply wait for the next store."""


class LiveLinkError(ValueError):
    """The live link to 3D Slicer cannot serve (e.g. its port is taken); the message says what to do."""


class StoreRefused(StoreError):
    """Store SN refused by its guard (stale IMU or fix, probe moving, window not full, the camera's insertion lost
    while it moved); the message says why. ``overridable``: the operator may store anyway (the override is put on
    record)."""

    def __init__(self, reason: str, overridable: bool = False):
        super().__init__(reason)
        self.overridable = bool(overridable)


class StoreNeedsConfirmation(StoreError):
    """A store close to a node already stored: the message is the question to ask, ``near`` that node's id."""

    def __init__(self, question: str, near: str):
        super().__init__(question)
        self.near = near
