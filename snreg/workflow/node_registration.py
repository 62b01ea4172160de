"""Register preop nodes to intraop nodes as ``snreg register`` does: the one place that decides what a registration
of two node files is given, shared by the command and the headless demo.

Why: the demo once registered with the labels and without the nodes' covariances while ``snreg register`` used the
covariances by default, so the two printed different confidences for one session (issue 35). Both now call
:func:`register_nodes`: each side's covariances are given when every node of that side has one
(:func:`node_covariances`), the labels only when asked for, the landmarks of both files paired by name.

>>> covariances = node_covariances(preop.nodes, intraop.nodes)          # {"intraop": (M,3,3) | None, "preop": ...}
>>> result = register_nodes(preop, intraop, labels=True, down=session_gravity(session).down)
"""

from __future__ import annotations

import numpy as np

from snreg.nodes import NodeFile, NodeSet
from snreg.registration import RegistrationResult, register


def node_covariances(preop: NodeSet, intraop: NodeSet, use: bool = True) -> dict[str, np.ndarray | None]:
    """``{"intraop", "preop"}``: each side's covariances (N, 3, 3) mm^2 when every node of it has one, else None (and
    both None when not ``use``: ``snreg register --no-covariances``)."""
    if not use:
        return {"intraop": None, "preop": None}
    return {"intraop": intraop.known_cov, "preop": preop.known_cov}


def register_nodes(preop: NodeFile, intraop: NodeFile, *, method: str = "global", labels: bool = False,
                   covariances: bool = True, initial: np.ndarray | None = None, down=None, seed: int = 0,
                   max_rotation_deg: float = 60.0, max_translation_mm: float = 60.0,
                   landmark_sd_mm: float = 2.0) -> RegistrationResult:
    """``register`` of ``preop``'s nodes to ``intraop``'s (NodeFiles: nodes and landmarks apart), given each side's
    covariances unless ``covariances`` is False, both sides' labels when ``labels``, and the landmarks both files
    hold (paired by name); ``initial``/``down`` the start (:mod:`snreg.workflow.registration_start`). Raises as
    ``register`` does (NoFitError, ValueError)."""
    cov = node_covariances(preop.nodes, intraop.nodes, covariances)
    marks = [None if not len(side.landmarks) else side.landmarks for side in (preop, intraop)]
    return register(preop.nodes.xyz, intraop.nodes.xyz, method=method,
                    preop_labels=preop.nodes.labels if labels else None,
                    intraop_labels=intraop.nodes.labels if labels else None,
                    initial=initial, max_rotation_deg=max_rotation_deg, max_translation_mm=max_translation_mm,
                    seed=seed, intraop_cov=cov["intraop"], preop_cov=cov["preop"],
                    preop_landmarks=marks[0], intraop_landmarks=marks[1], landmark_sd_mm=landmark_sd_mm, down=down)
