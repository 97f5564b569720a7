"""Step 3-4 of the paper (§5-6): the DRM as a graph and the max-probability path.

The DRM's edges come from the knowledge base (``reachable/6`` in
``prolog/drm.pl``).  The best path maximises the product of edge
probabilities, i.e. minimises the sum of -log p (Dijkstra, networkx).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import networkx as nx


@dataclass(frozen=True)
class DrmEdge:
    source: str
    target: str
    p: float
    method: str
    via: tuple[str, ...] = ()


@dataclass(frozen=True)
class DrmPath:
    """A path on the DRM: landmarks, the edges taken, and the product of their p."""

    nodes: list[str]
    steps: list[DrmEdge] = field(default_factory=list)

    @property
    def probability(self) -> float:
        return math.prod(s.p for s in self.steps)


def build_drm(nodes: Iterable[str], edges: Iterable[DrmEdge]) -> nx.DiGraph:
    """Directed graph with edge attributes p, method, via and cost = -log p (p > 0 only)."""
    g = nx.DiGraph()
    g.add_nodes_from(nodes)
    for e in edges:
        if e.p > 0.0:
            g.add_edge(e.source, e.target, p=e.p, method=e.method, via=e.via,
                       cost=-math.log(e.p))
    return g


def edges_from_records(records: Iterable[dict[str, Any]]) -> list[DrmEdge]:
    """DrmEdges from the knowledge base's JSON edge records."""
    return [DrmEdge(r["from"], r["to"], float(r["p"]), r["method"], tuple(r.get("via", [])))
            for r in records]


def max_probability_path(g: nx.DiGraph, source: str, target: str) -> DrmPath | None:
    """The path maximising the product of p (Dijkstra on -log p); None if unreachable."""
    if source == target:
        return DrmPath(nodes=[source])
    try:
        nodes = nx.dijkstra_path(g, source, target, weight="cost")
    except nx.NetworkXNoPath:
        return None
    steps = []
    for a, b in zip(nodes, nodes[1:], strict=False):
        d = g.edges[a, b]
        steps.append(DrmEdge(a, b, d["p"], d["method"], tuple(d["via"])))
    return DrmPath(nodes=nodes, steps=steps)
