"""Work on a closed session file: read its nodes and landmarks (``snreg register``), mark a registration final
(review)."""

from __future__ import annotations

from pathlib import Path

import h5py

from snreg.nodes import NodeFile
from snreg.session import writer
from snreg.session.journal import Journal, journal_path
from snreg.session.schema import SessionError
from snreg.session.session import Session


def set_final_in_file(path: str | Path, n: int | None) -> None:
    """Mark registration ``n`` final (None: unmark) in a session file that is not open for recording (review).

    Journal line first, then the attribute, as :meth:`Session.set_final_registration`; unlike
    :meth:`Session.resume` nothing else is rewritten. :class:`SessionError` in one sentence when the file cannot be
    marked (no such registration, damaged, or open for recording elsewhere)."""
    path = Path(path)
    with Session.open(path) as session:
        if session.damaged:
            raise SessionError(f"{path}: the HDF5 file is damaged; run 'snreg session recover' before marking it")
        n = session._known_registration(n)
    try:
        h5 = h5py.File(path, "r+")
    except OSError as err:
        raise SessionError(f"{path}: cannot be opened for writing ({err}); is it being recorded?") from None
    with h5:
        journal = Journal(journal_path(path))
        try:
            journal.append("final", {"n": n})
        finally:
            journal.close()
        writer.write_final(h5, n)
        h5.flush()


def read_intraop(path: str | Path) -> NodeFile:
    """The intraop nodes of a session file and, apart, its landmarks (trocar frame, mm), for ``snreg register``."""
    with Session.open(path) as session:
        return NodeFile(session.intraop_nodes(), session.intraop_landmarks())
