"""Small questions about node sets that the registration panel asks: are there any, are two the same, the set
without some ids, how many in words, was a stored registration made from these sets."""

from __future__ import annotations

import numpy as np

from snreg.nodes import NodeSet


def has_nodes(nodes: NodeSet | None) -> bool:
    return nodes is not None and len(nodes) > 0


def same_nodes(a: NodeSet | None, b: NodeSet | None) -> bool:
    return a is not None and b is not None and a.ids == b.ids and np.allclose(a.xyz, b.xyz)


def without(nodes: NodeSet, ids: set[str]) -> NodeSet:
    """The node set without the nodes of these ids (the others keep their counts and covariances)."""
    keep = [k for k, i in enumerate(nodes.ids) if i not in ids]
    if len(keep) == len(nodes):
        return nodes
    return NodeSet([nodes.ids[k] for k in keep], [nodes.labels[k] for k in keep], nodes.xyz[keep],
                   None if nodes.counts is None else nodes.counts[keep], frame=nodes.frame,
                   cov=None if nodes.cov is None else nodes.cov[keep])


def count_text(nodes: NodeSet) -> str:
    return f"{len(nodes)} node{'s' * (len(nodes) != 1)}"


def made_from(stored, preop: NodeSet, intraop: NodeSet | None) -> bool:
    """Whether a stored registration paired these very node sets (by their ids; by their counts in files written
    before ids were stored)."""
    if intraop is None:
        return False
    if stored.intraop_ids is not None:
        return stored.preop_ids == preop.ids and stored.intraop_ids == intraop.ids
    pairing = stored.result.pairing
    return len(pairing) == len(intraop) and int(np.max(pairing, initial=-1)) < len(preop)
