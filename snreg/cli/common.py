"""What several ``snreg`` subcommands share: argument types and reading a rough initial transform."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from snreg.errors import SessionError, UserError

__all__ = ["floats", "ints", "read_initial"]


def floats(text: str) -> tuple[float, ...]:
    """An argparse type: comma-separated numbers."""
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def ints(text: str) -> tuple[int, ...]:
    """An argparse type: comma-separated integers."""
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def read_initial(path: str | None) -> np.ndarray | None:
    """A 4x4 ``intraop_from_preop`` from a text or JSON file (``{"transform": ...}`` or a bare matrix), or the initial
    alignment stored with a session's last registration (``.h5``); None if no path."""
    if path is None:
        return None
    if Path(path).suffix.lower() in (".h5", ".hdf5"):
        return session_initial(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
        data = json.loads(text) if path.endswith(".json") else np.loadtxt(path, delimiter=None if "," not in text else ",")
        matrix = np.asarray(data.get("transform", data) if isinstance(data, dict) else data, dtype=float)
    except (OSError, ValueError) as err:
        raise UserError(f"{path}: cannot read a 4x4 initial transform ({err})") from None
    if matrix.shape != (4, 4):
        raise UserError(f"{path}: the initial transform must be 4x4, got shape {matrix.shape}")
    return matrix


def session_initial(path: str) -> np.ndarray:
    """The initial alignment stored with the session's last registration that kept one."""
    from snreg.session import Session  # h5py only when a session is read
    try:
        with Session.open(path) as session:
            stored = [r.result.initial for r in session.registrations() if r.result.initial is not None]
    except (SessionError, OSError) as err:
        raise UserError(str(err)) from None
    if not stored:
        raise UserError(f"{path}: no registration in this session kept its initial alignment; give --initial as a "
                        "4x4 text or JSON file")
    return stored[-1]
