"""The list of the SPECT nodes not found yet, in words: after a registration, each missing node with its 90 % bound
(and, where asked, where the registration maps it in the trocar frame).

Why: the surgeon's question during the procedure is "which SPECT nodes have I not removed yet, and where are
they?"; the acquisition screen lists them from the latest registration, and the way to each from the probe tip is
said in the endoscope's view by :mod:`snreg.workflow.navigation`.

>>> targets = missing_nodes(preop, result)           # snreg.registration.report
>>> targets_text(targets, where=False)               # "P4 OBT R: expected within 6 mm (90 %)"
"""

from __future__ import annotations

from snreg.registration.report import MissingNode

__all__ = ["targets_text"]


def targets_text(targets: list[MissingNode], where: bool = True) -> str:
    """One line per missing node: id, label, its expected error (the registration's 90 % bound on how far it really is
    from where it is mapped) and, with ``where``, that position: "P4 OBT R: expected within 6 mm (90 %) of (12, -30,
    85) mm"."""
    if not targets:
        return "every SPECT node is paired"
    return "\n".join(f"{' '.join(filter(None, (t.preop_id, t.preop_label)))}: expected within {t.bound_mm:.0f} mm (90 %)"
                     + (f" of ({t.mapped_xyz[0]:.0f}, {t.mapped_xyz[1]:.0f}, {t.mapped_xyz[2]:.0f}) mm" if where else "")
                     for t in targets)
