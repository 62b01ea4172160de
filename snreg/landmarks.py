"""Anatomical landmarks' names: the vocabulary offered and the one rule every name passes (files, session, store).

Why one place below the node files and the labels: a landmark pairs with its partner by name alone, so the same name
must come out the same wherever it was typed (a CSV's ``id``, a Slicer control point's label, the app's Store
landmark): "Aortic  bifurcation" and "aortic bifurcation" are one landmark. A name that looks like an id snreg gives
(``P3``, ``SN2``) is refused, so a landmark is never taken for a node or a hot spot.
"""

from __future__ import annotations

import re

__all__ = ["LANDMARKS", "KINDS", "NODE", "LANDMARK", "MAX_NAME_LENGTH", "landmark_name", "landmark_key", "in_vocabulary",
           "kind_of"]

# Found on the CT and touched with the probe in surgery (thesis §6: the pelvic arteries deform less than 2.1 mm): the
# names offered in the app and the command line; any other name may be used.
LANDMARKS = ("aortic bifurcation", "right common iliac bifurcation", "left common iliac bifurcation",
             "right internal iliac origin", "left internal iliac origin", "top of the pubic symphysis")

NODE, LANDMARK = "node", "landmark"
KINDS = (NODE, LANDMARK)          # a node file's ``kind`` column, a stored intraop point's ``kind``
MAX_NAME_LENGTH = 64
_SNREG_ID = re.compile(r"(P|SN)\d+", re.IGNORECASE)        # the ids snreg gives preop and intraop nodes


def landmark_key(name) -> str:
    """What two spellings of one landmark share: case folded, inner whitespace collapsed, surrounding spaces dropped
    ("Aortic  Bifurcation " and "aortic bifurcation" are one key); landmarks pair by it."""
    return " ".join(str(name).split()).casefold()


_VOCABULARY = {landmark_key(name): name for name in LANDMARKS}


def landmark_name(name) -> str:
    """``name`` as snreg keeps it: whitespace collapsed, a vocabulary name in the vocabulary's spelling (any case),
    any other name as typed. ValueError in one sentence for an empty, over-long or control-character name, and for one
    that looks like a node id."""
    if not isinstance(name, str):
        raise ValueError(f"a landmark name must be text, not {type(name).__name__}")
    text = " ".join(name.split())
    if not text:
        raise ValueError("a landmark needs a name, e.g. 'aortic bifurcation'")
    if any(ord(c) < 32 or ord(c) == 127 for c in text):
        raise ValueError(f"landmark name {text!r} holds control characters; type it as plain text")
    if len(text) > MAX_NAME_LENGTH:
        raise ValueError(f"landmark name {text[:20]!r}... is {len(text)} characters long; keep it to "
                         f"{MAX_NAME_LENGTH}")
    if _SNREG_ID.fullmatch(text):
        raise ValueError(f"{text!r} looks like a node id, not a landmark name; name the landmark anatomically, e.g. "
                         "'aortic bifurcation'")
    return _VOCABULARY.get(landmark_key(text), text)


def in_vocabulary(name: str) -> bool:
    """Whether ``name`` is one of :data:`LANDMARKS` (any case and spacing)."""
    return landmark_key(name) in _VOCABULARY


def kind_of(value, default: str = NODE) -> str:
    """A ``kind`` cell or field as ``node`` or ``landmark`` (any case; empty or None: ``default``); ValueError in one
    sentence for anything else."""
    text = "" if value is None else str(value).strip().lower()
    if not text:
        return default
    if text not in KINDS:
        raise ValueError(f"kind {str(value).strip()!r} is neither 'node' nor 'landmark' (leave it empty for a node)")
    return text
