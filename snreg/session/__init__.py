"""Crash-safe HDF5 sessions (docs/design.md, Contracts "Session (HDF5)").

>>> with Session.create("s.h5", case_id="phantom-01") as s:
...     s.add_intraop_node("SN1", "OBT R", [1.0, 2.0, 3.0])   # durable once it returns
>>> Session.open("s.h5").intraop_nodes()                    # NodeSet, frame "trocar"

Anatomical landmarks touched with the probe are intraop points of kind ``landmark`` (``add_intraop_node(name, ...,
kind="landmark")``, :meth:`Session.intraop_landmarks`), kept, re-expressed and exported beside the nodes but never
among them: :meth:`Session.intraop_records` and :meth:`Session.intraop_nodes` give the nodes alone. The preop
landmarks are stored with the preop nodes (:meth:`Session.set_preop_nodes`, :meth:`Session.preop_landmarks`).

Nodes, node removals (undo), calibrations, preop sets and registrations go to a write-ahead journal
(``s.h5.journal``, fsynced) before the HDF5 file; :meth:`Session.open` merges the journal, and reads it alone
when a kill left the HDF5 file unreadable (``Session.damaged``); ``snreg session recover`` rebuilds a clean
file. :meth:`Session.resume` reopens a session to go on recording into it. The journal keeps every node ever
stored, so an undone node stays on record there.

One stored registration may be marked final, the one that counts (:meth:`Session.set_final_registration`;
:func:`set_final_in_file` for a closed file): the attribute ``final=True`` on ``registration/<n>``, journal first;
files without it have none marked.

What happened besides the nodes (a store refused and why, nodes re-expressed under a new calibration with their old
values, an acquisition started) goes to the ``events`` log (:meth:`Session.log_event`, :meth:`Session.events`),
journal first as well. A re-expression is one journal line, so a kill during it leaves every node either all old
or all new, never half.
"""

from snreg.session.closed import read_intraop, set_final_in_file
from snreg.session.schema import IntraopNode, SessionError, StoredRegistration, calibration_version, validate_case_id
from snreg.session.session import Session

__all__ = ["Session", "SessionError", "IntraopNode", "StoredRegistration", "read_intraop", "validate_case_id",
           "calibration_version", "set_final_in_file"]
