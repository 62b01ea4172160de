"""How screens and texts name the preop nodes beside the intraop ones, so that a pairing is never misread.

Why: snreg names SPECT nodes ``P1, P2...`` and stored nodes ``SN1, SN2...``, but a preop node file from elsewhere
may use ``SN1...`` too, and "SN1 -> SN4" is then easy to read backwards. When any preop id equals an intraop id,
every preop id is shown with :data:`PREOP_MARK` (``P:SN4``); otherwise ids are shown as they are. Only what is
shown changes: files and JSON keep the real ids.

>>> shown_preop_ids(["SN1", "SN2"], ["SN1"])
['P:SN1', 'P:SN2']
>>> pair_text(row)                 # "SN1 -> P3", "SN5 -> P3 (with SN4)", "SN6 -> none"
"""

from __future__ import annotations

from dataclasses import replace

from snreg.registration.report import MissingNode, PairRow, pair_rows

__all__ = ["PREOP_MARK", "ids_collide", "shown_preop_ids", "marked_rows", "marked_missing", "pair_text", "pairs_line"]

PREOP_MARK = "P:"


def ids_collide(preop_ids, intraop_ids) -> bool:
    """Whether any preop id is also an intraop id."""
    return not set(map(str, preop_ids)).isdisjoint(map(str, intraop_ids))


def shown_preop_ids(preop_ids, intraop_ids) -> list[str]:
    """The preop ids as screens show them: all marked ``P:`` when any collides with an intraop id, else unchanged."""
    preop_ids = [str(i) for i in preop_ids]
    return [PREOP_MARK + i for i in preop_ids] if ids_collide(preop_ids, intraop_ids) else preop_ids


def marked_rows(rows: list[PairRow], preop_ids) -> list[PairRow]:
    """``rows`` with their preop ids as :func:`shown_preop_ids` shows them (``preop_ids``: the whole preop set, as
    a preop node left unpaired can collide too); a node from no hot spot keeps "none"."""
    if not ids_collide(preop_ids, [row.intraop_id for row in rows]):
        return list(rows)
    return [replace(row, preop_id=PREOP_MARK + row.preop_id) if row.paired else row for row in rows]


def marked_missing(missing: list[MissingNode], intraop_ids, preop_ids) -> list[MissingNode]:
    """Missing preop nodes named as :func:`shown_preop_ids` names them (for the guidance and the hot spots the feeds draw)."""
    if not ids_collide(preop_ids, intraop_ids):
        return list(missing)
    return [replace(node, preop_id=PREOP_MARK + node.preop_id) for node in missing]


def pair_text(row: PairRow) -> str:
    """``"SN5 -> P3 (with SN4)"``: the intraop node, the hot spot it came from ("none" for no imaged hot spot), and
    the other nodes that came from it."""
    shared = f" (with {', '.join(row.shared_with)})" if row.shared_with else ""
    return f"{row.intraop_id} -> {row.preop_id}{shared}"


def pairs_line(preop, intraop, result) -> str:
    """Every intraop node's claim on one line, as screens show them: ``"SN1 -> P1; SN2 -> P3 (with SN5); ..."`` (for
    the live link's status and other one-line places); ``preop``/``intraop``: the node sets registered."""
    return "; ".join(pair_text(row) for row in marked_rows(pair_rows(preop, intraop, result), preop.ids))
