"""The spatial object tree of the paper (Sec. IV-A): two coordinate interval trees, T_x and T_y.

x and y are the world's horizontal axes (`ndfa.core.conventions.HORIZONTAL_AXES`): a cell is a
column over the ground, so objects stacked or seen at odd heights stay neighbours.

Each tree cuts its axis into intervals of fixed length `l`. An interval (a node) is created by the
first object center that falls outside every existing one, as [t - l/2, t + l/2]; it holds the
ids of the objects whose center coordinate lies in it. The neighbourhood of a point is the set of
objects in both the T_x node and the T_y node that the point falls in: a cell of about l x l.

Nodes never overlap: a new interval is clipped where it would run into a neighbouring one (the
paper's ordering, left.max < parent.min, presumes disjoint intervals but does not say how a
center within l/2 of an existing node is handled; clipping keeps "the first center decides" and
leaves no point in two nodes).

The tree is kept as a sorted array of interval bounds searched by bisection: the implicit form
of a perfectly balanced binary search tree, so a point query costs O(log n) in the number of
nodes whatever the insertion order. An insertion shifts the array (O(n) memmove), which is
negligible: the number of nodes is the extent of the map over l, not the number of objects.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from ndfa.core.conventions import HORIZONTAL_AXES

X, Y = HORIZONTAL_AXES  # the world axes that T_x and T_y cut


@dataclass
class IntervalNode:
    low: float
    high: float
    objects: set[int] = field(default_factory=set)


class IntervalTree:
    """One axis: disjoint intervals of length <= `length`, each holding object ids."""

    def __init__(self, length: float) -> None:
        if not length > 0:
            raise ValueError(f"interval length must be positive, got {length}")
        self.length = length
        self._lows: list[float] = []
        self._nodes: list[IntervalNode] = []

    def __len__(self) -> int:
        return len(self._nodes)

    @property
    def nodes(self) -> list[IntervalNode]:
        """The nodes in axis order."""
        return list(self._nodes)

    def find(self, t: float) -> IntervalNode | None:
        """The node whose interval holds `t`, or None."""
        i = bisect.bisect_right(self._lows, t) - 1
        if i >= 0 and t <= self._nodes[i].high:
            return self._nodes[i]
        return None

    def find_or_create(self, t: float) -> IntervalNode:
        """The node holding `t`, created (and clipped to its neighbours) if there is none."""
        node = self.find(t)
        if node is not None:
            return node
        i = bisect.bisect_right(self._lows, t)
        low, high = t - self.length / 2, t + self.length / 2
        if i > 0:
            low = max(low, np.nextafter(self._nodes[i - 1].high, np.inf))
        if i < len(self._nodes):
            high = min(high, np.nextafter(self._nodes[i].low, -np.inf))
        node = IntervalNode(float(low), float(high))
        self._lows.insert(i, node.low)
        self._nodes.insert(i, node)
        return node


Cell = tuple[IntervalNode, IntervalNode]  # (T_x node, T_y node): about l x l of ground


class ObjectTree:
    """T = (T_x, T_y): where each object is, and which objects are neighbours of a point."""

    def __init__(self, length: float) -> None:
        self.x = IntervalTree(length)
        self.y = IntervalTree(length)
        self._cells: dict[int, tuple[IntervalNode, IntervalNode]] = {}

    def __len__(self) -> int:
        return len(self._cells)

    def insert(self, object_id: int, center: np.ndarray) -> None:
        """Place (or move) `object_id` at `center` (x, y, z): in the nodes its x and y land in."""
        self.remove(object_id)
        node_x, node_y = self.x.find_or_create(float(center[X])), self.y.find_or_create(float(center[Y]))
        node_x.objects.add(object_id)
        node_y.objects.add(object_id)
        self._cells[object_id] = (node_x, node_y)

    def remove(self, object_id: int) -> None:
        cell = self._cells.pop(object_id, None)
        if cell is not None:
            for node in cell:
                node.objects.discard(object_id)

    def cell_at(self, point: np.ndarray) -> Cell | None:
        """The (T_x, T_y) nodes that `point` falls in, or None where either axis has no node."""
        node_x, node_y = self.x.find(float(point[X])), self.y.find(float(point[Y]))
        if node_x is None or node_y is None:
            return None
        return node_x, node_y

    def neighbourhood(self, point: np.ndarray) -> set[int]:
        """Ids of the objects in both the T_x and the T_y node that `point` falls in (empty if none)."""
        cell = self.cell_at(point)
        if cell is None:
            return set()
        small, large = sorted((cell[0].objects, cell[1].objects), key=len)
        return {i for i in small if i in large}

    def cell(self, object_id: int) -> Cell:
        """The (T_x, T_y) nodes that hold `object_id`."""
        return self._cells[object_id]


def in_cell(cell: Cell, points: np.ndarray) -> np.ndarray:
    """Which of `points` (N, 3) lie in `cell` (a tree of another session may never have held them): (N,) bool."""
    node_x, node_y = cell
    x, y = points[:, X], points[:, Y]
    return (x >= node_x.low) & (x <= node_x.high) & (y >= node_y.low) & (y <= node_y.high)
