"""The spatial object tree of the paper (Sec. IV-A): two coordinate interval trees, T_x and T_y,
and optionally a third, T_z, over height.

x and y are the world's horizontal axes (`ndfa.core.conventions.HORIZONTAL_AXES`). With T_x and
T_y alone (the paper's tree) a cell is a column over the ground, so objects on shelves above one
another are neighbours. T_z (the extension the paper calls straightforward, ndfa's
`LevelsConfig`) cuts the column into slabs along the world's up axis: a cell is then a box, and
objects on surfaces a slab's height apart or more are not neighbours.

Each tree cuts its axis into intervals of fixed length `l`. An interval (a node) is created by the
first object center that falls outside every existing one, as [t - l/2, t + l/2]; it holds the
ids of the objects whose center coordinate lies in it. The neighbourhood of a point is the set of
objects in both the T_x node and the T_y node that the point falls in: a cell of about l x l.

Nodes never overlap: a new interval is clipped where it would run into a neighbouring one (the
paper's ordering, left.max < parent.min, presumes disjoint intervals but does not say how a
center within l/2 of an existing node is handled; clipping keeps "the first center decides" and
leaves no point in two nodes).

A point near a cell's edge may belong to the cell across it: a measurement's center is noisy, and a
target object's center carries T_rel's error into the source world. Queries take a `margin`: the
region they look in is every cell that the square (with T_z, the cube) of half-side `margin` around
the point touches (the cell itself when the margin is 0, the paper's rule).

The tree is kept as a sorted array of interval bounds searched by bisection: the implicit form
of a perfectly balanced binary search tree, so a point query costs O(log n) in the number of
nodes whatever the insertion order. An insertion shifts the array (O(n) memmove), which is
negligible: the number of nodes is the extent of the map over l, not the number of objects.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from ndfa.core.conventions import HORIZONTAL_AXES, UP_AXIS

X, Y = HORIZONTAL_AXES  # the world axes that T_x and T_y cut
Z = UP_AXIS             # the one T_z cuts


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

    def overlapping(self, low: float, high: float) -> tuple[IntervalNode, ...]:
        """The nodes that share a point with [low, high], in axis order."""
        first = max(bisect.bisect_right(self._lows, low) - 1, 0)
        last = bisect.bisect_right(self._lows, high)
        return tuple(n for n in self._nodes[first:last] if n.high >= low)

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


Cell = tuple[IntervalNode, ...]  # (T_x node, T_y node[, T_z node]): about l x l of ground[, h high]


def _within(values: np.ndarray, nodes: tuple[IntervalNode, ...], margin: float) -> np.ndarray:
    inside: np.ndarray = np.zeros(len(values), dtype=bool)
    for node in nodes:
        inside |= (values >= node.low - margin) & (values <= node.high + margin)
    return inside


@dataclass(frozen=True)
class Region:
    """Cells of one tree around a point: every pair (triple) of a T_x node in `x`, a T_y node in
    `y` (and a T_z node in `z`; None: the tree has no T_z, a cell is a column)."""

    x: tuple[IntervalNode, ...]
    y: tuple[IntervalNode, ...]
    z: tuple[IntervalNode, ...] | None = None

    def objects(self) -> set[int]:
        """Ids of the objects in the region (each object sits in one node of each tree)."""
        axes = (self.x, self.y) if self.z is None else (self.x, self.y, self.z)
        found: set[int] = set().union(*(n.objects for n in axes[0]))
        for nodes in axes[1:]:
            found &= set().union(*(n.objects for n in nodes))
        return found

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Which of `points` (N, 3) lie in the region grown by `margin` on every side (a tree of
        another session may never have held them): (N,) bool."""
        inside: np.ndarray = _within(points[:, X], self.x, margin) & _within(points[:, Y], self.y, margin)
        if self.z is not None:
            inside &= _within(points[:, Z], self.z, margin)
        return inside


class ObjectTree:
    """T = (T_x, T_y[, T_z]): where each object is, and which objects are neighbours of a point.

    `length`: l, the interval length of T_x and T_y; `height`: that of T_z, or None for the
    paper's tree without one."""

    def __init__(self, length: float, height: float | None = None) -> None:
        self.x = IntervalTree(length)
        self.y = IntervalTree(length)
        self.z = None if height is None else IntervalTree(height)
        self._cells: dict[int, Cell] = {}

    def __len__(self) -> int:
        return len(self._cells)

    def node_counts(self) -> tuple[int, ...]:
        """The nodes of each tree (T_x, T_y[, T_z])."""
        return (len(self.x), len(self.y)) + (() if self.z is None else (len(self.z),))

    def insert(self, object_id: int, center: np.ndarray) -> None:
        """Place (or move) `object_id` at `center` (x, y, z): in the nodes its coordinates land in."""
        self.remove(object_id)
        cell: Cell = (self.x.find_or_create(float(center[X])), self.y.find_or_create(float(center[Y])))
        if self.z is not None:
            cell += (self.z.find_or_create(float(center[Z])),)
        for node in cell:
            node.objects.add(object_id)
        self._cells[object_id] = cell

    def remove(self, object_id: int) -> None:
        cell = self._cells.pop(object_id, None)
        if cell is not None:
            for node in cell:
                node.objects.discard(object_id)

    def region(self, point: np.ndarray, margin: float = 0.0) -> Region:
        """The cells within `margin` of `point` (per axis): see the module docstring."""
        x, y = float(point[X]), float(point[Y])
        z = None if self.z is None else self.z.overlapping(float(point[Z]) - margin, float(point[Z]) + margin)
        return Region(self.x.overlapping(x - margin, x + margin), self.y.overlapping(y - margin, y + margin), z)

    def neighbourhood(self, point: np.ndarray, margin: float = 0.0) -> set[int]:
        """Ids of the objects in a node of every tree within `margin` of `point` (empty if none);
        with margin 0, the objects of the cell `point` falls in."""
        return self.region(point, margin).objects()

    def cell(self, object_id: int) -> Cell:
        """The (T_x, T_y[, T_z]) nodes that hold `object_id`."""
        return self._cells[object_id]
