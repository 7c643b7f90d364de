"""Grid geometry: through lanes, intersections, conflict points and control areas.

Coordinates are metres with x pointing east and y north. Intersection ``(r, c)`` (row ``r``
counted from the south, column ``c`` from the west) has its centre at
``((c + 1) L, (r + 1) L)`` with ``L`` the segment length, so every boundary approach and exit
link is one segment long. Traffic is right-handed: an eastbound lane runs ``lane_offset_m``
south of its road's centreline, a northbound lane the same distance east of it, and so on.

A vehicle's position is its distance ``s`` [m] along its through lane from the lane's entry;
everything 2-D is derived from ``(lane, s)``.

Lane order: eastbound rows ``0..R-1``, westbound rows, northbound columns ``0..C-1``,
southbound columns. Intersection ids are ``r * C + c``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import graph_kernel

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Lane headings, in lane order blocks.
HEADINGS = ("east", "west", "north", "south")


@dataclass(frozen=True)
class GridNetwork:
    """Static geometry of an R x C grid (numpy arrays, built once per config).

    Attributes:
        n_lanes: number of through lanes, 2R + 2C.
        lane_length: (n_lanes,) lane length [m].
        lane_origin: (n_lanes, 2) entry point [m].
        lane_dir: (n_lanes, 2) unit travel direction.
        lane_horizontal: (n_lanes,) True for east/westbound lanes.
        lane_heading: (n_lanes,) index into :data:`HEADINGS`.
        intersection_xy: (n_intersections, 2) centres [m].
        lane_centres_s: (n_lanes, n_on_lane_max) distance of each crossed intersection centre
            from the lane entry [m], in travel order, padded with ``inf``.
        lane_intersections: (n_lanes, n_on_lane_max) ids of those intersections, padded -1.
        cp_xy: (n_cp, 2) conflict points [m].
        cp_lane: (n_cp, 2) the horizontal and the vertical lane crossing there.
        cp_s: (n_cp, 2) distance of the point from each lane's entry [m].
        cp_intersection: (n_cp,) intersection of each conflict point.
        lane_cp: (n_lanes, n_cp_lane_max) conflict points of each lane in travel order, -1 pad.
        lane_cp_s: (n_lanes, n_cp_lane_max) their distance from the lane entry [m], inf pad.
        lane_cp_other_lane: (n_lanes, n_cp_lane_max) the crossing lane at each point, -1 pad.
        lane_cp_other_s: (n_lanes, n_cp_lane_max) the point's distance on the crossing lane.
    """

    rows: int
    cols: int
    segment_length_m: float
    lane_offset_m: float
    control_radius_m: float
    n_lanes: int
    lane_length: FloatArray
    lane_origin: FloatArray
    lane_dir: FloatArray
    lane_horizontal: NDArray[np.bool_]
    lane_heading: IntArray
    intersection_xy: FloatArray
    lane_centres_s: FloatArray
    lane_intersections: IntArray
    cp_xy: FloatArray
    cp_lane: IntArray
    cp_s: FloatArray
    cp_intersection: IntArray
    lane_cp: IntArray
    lane_cp_s: FloatArray
    lane_cp_other_lane: IntArray
    lane_cp_other_s: FloatArray

    @property
    def n_intersections(self) -> int:
        return self.rows * self.cols

    @property
    def n_cp(self) -> int:
        return int(self.cp_xy.shape[0])

    @property
    def extent_m(self) -> tuple[float, float]:
        """Width and height of the network [m]."""
        return ((self.cols + 1) * self.segment_length_m, (self.rows + 1) * self.segment_length_m)

    @classmethod
    def from_config(cls, config: MiVeCCConfig) -> GridNetwork:
        return build_grid(
            config.rows, config.cols, config.segment_length_m, config.lane_offset_m,
            config.control_radius_m,
        )

    def xy(self, lane: IntArray, s: FloatArray) -> FloatArray:
        """2-D positions [m] of points at distance ``s`` along ``lane`` (broadcasting)."""
        return self.lane_origin[lane] + s[..., None] * self.lane_dir[lane]

    def control_area(self, lane: IntArray, s: FloatArray) -> IntArray:
        """Intersection whose control area holds each point, or -1 outside every area.

        A point belongs to intersection ``i`` when it is on one of ``i``'s lanes within
        ``control_radius_m`` (along the lane, half-open ``[-r, r)``) of its centre.
        """
        seg = self.segment_length_m
        if graph_kernel.HAVE_NUMBA and lane.ndim == 1 and s.ndim == 1 and lane.dtype == np.int64:
            return graph_kernel.control_area(lane, s.astype(np.float64, copy=False),
                                             self.lane_centres_s, self.lane_intersections,
                                             self.control_radius_m, seg)
        n_on = self.lane_centres_s.shape[1]
        k = np.clip(np.floor((s + self.control_radius_m) / seg).astype(np.int64) - 1, 0, n_on - 1)
        centre = self.lane_centres_s[lane, k]
        inside = (s >= centre - self.control_radius_m) & (s < centre + self.control_radius_m)
        return np.where(inside, self.lane_intersections[lane, k], -1)

    def next_stop_s(self, lane: IntArray, s: FloatArray) -> FloatArray:
        """Distance from the lane entry of the next conflict point ahead, or the lane end [m]."""
        cps = self.lane_cp_s[lane]  # (..., n_cp_lane)
        ahead = np.where(cps >= s[..., None], cps, np.inf).min(axis=-1)
        return np.where(np.isfinite(ahead), ahead, self.lane_length[lane])


def _add_lane(origin: list, direction: list, length: list, heading: list,
              start: tuple, unit: tuple, size: float, head: int) -> None:
    origin.append(start)
    direction.append(unit)
    length.append(size)
    heading.append(head)


def build_grid(
    rows: int, cols: int, segment_length_m: float, lane_offset_m: float,
    control_radius_m: float,
) -> GridNetwork:
    """Build the geometry of a ``rows`` x ``cols`` grid (see the module docstring)."""
    seg, off = float(segment_length_m), float(lane_offset_m)
    width, height = (cols + 1) * seg, (rows + 1) * seg
    ys = (np.arange(rows) + 1) * seg  # road centrelines of the rows
    xs = (np.arange(cols) + 1) * seg

    origin, direction, length, heading = [], [], [], []
    for y in ys:  # eastbound: south side of the road
        _add_lane(origin, direction, length, heading, (0.0, y - off), (1.0, 0.0), width, 0)
    for y in ys:  # westbound: north side
        _add_lane(origin, direction, length, heading, (width, y + off), (-1.0, 0.0), width, 1)
    for x in xs:  # northbound: east side
        _add_lane(origin, direction, length, heading, (x + off, 0.0), (0.0, 1.0), height, 2)
    for x in xs:  # southbound: west side
        _add_lane(origin, direction, length, heading, (x - off, height), (0.0, -1.0), height, 3)
    lane_origin = np.asarray(origin, dtype=np.float64)
    lane_dir = np.asarray(direction, dtype=np.float64)
    lane_length = np.asarray(length, dtype=np.float64)
    lane_heading = np.asarray(heading, dtype=np.int64)
    lane_horizontal = lane_heading < 2
    n_lanes = lane_origin.shape[0]

    # Which intersections each lane passes, in travel order.
    n_on_max = max(rows, cols)
    lane_centres_s = np.full((n_lanes, n_on_max), np.inf)
    lane_intersections = np.full((n_lanes, n_on_max), -1, dtype=np.int64)
    for lane in range(n_lanes):
        if lane_horizontal[lane]:
            r = lane % rows
            ids = np.array([r * cols + c for c in range(cols)])
            s_on_lane = (xs - lane_origin[lane, 0]) * lane_dir[lane, 0]
        else:
            c = (lane - 2 * rows) % cols
            ids = np.array([r * cols + c for r in range(rows)])
            s_on_lane = (ys - lane_origin[lane, 1]) * lane_dir[lane, 1]
        order = np.argsort(s_on_lane)
        lane_centres_s[lane, : ids.size] = s_on_lane[order]
        lane_intersections[lane, : ids.size] = ids[order]

    intersection_xy = np.array(
        [(xs[c], ys[r]) for r in range(rows) for c in range(cols)], dtype=np.float64
    )

    # Conflict points: every horizontal lane crosses every vertical lane once.
    cp_xy, cp_lane, cp_s, cp_int = [], [], [], []
    horizontal = np.flatnonzero(lane_horizontal)
    vertical = np.flatnonzero(~lane_horizontal)
    for h in horizontal:
        for v in vertical:
            point = np.array([lane_origin[v, 0], lane_origin[h, 1]])
            s_h = float(np.dot(point - lane_origin[h], lane_dir[h]))
            s_v = float(np.dot(point - lane_origin[v], lane_dir[v]))
            r, c = h % rows, (v - 2 * rows) % cols
            cp_xy.append(point)
            cp_lane.append((h, v))
            cp_s.append((s_h, s_v))
            cp_int.append(int(r * cols + c))
    cp_xy_a = np.asarray(cp_xy, dtype=np.float64)
    cp_lane_a = np.asarray(cp_lane, dtype=np.int64)
    cp_s_a = np.asarray(cp_s, dtype=np.float64)

    n_cp_lane = max(2 * rows, 2 * cols)
    lane_cp = np.full((n_lanes, n_cp_lane), -1, dtype=np.int64)
    lane_cp_s = np.full((n_lanes, n_cp_lane), np.inf)
    lane_cp_other_lane = np.full((n_lanes, n_cp_lane), -1, dtype=np.int64)
    lane_cp_other_s = np.full((n_lanes, n_cp_lane), np.inf)
    for lane in range(n_lanes):
        side = 0 if lane_horizontal[lane] else 1
        ids = np.flatnonzero(cp_lane_a[:, side] == lane)
        ids = ids[np.argsort(cp_s_a[ids, side])]
        lane_cp[lane, : ids.size] = ids
        lane_cp_s[lane, : ids.size] = cp_s_a[ids, side]
        lane_cp_other_lane[lane, : ids.size] = cp_lane_a[ids, 1 - side]
        lane_cp_other_s[lane, : ids.size] = cp_s_a[ids, 1 - side]

    return GridNetwork(
        rows=rows, cols=cols, segment_length_m=seg, lane_offset_m=off,
        control_radius_m=float(control_radius_m), n_lanes=n_lanes, lane_length=lane_length,
        lane_origin=lane_origin, lane_dir=lane_dir, lane_horizontal=lane_horizontal,
        lane_heading=lane_heading, intersection_xy=intersection_xy,
        lane_centres_s=lane_centres_s, lane_intersections=lane_intersections, cp_xy=cp_xy_a,
        cp_lane=cp_lane_a, cp_s=cp_s_a, cp_intersection=np.asarray(cp_int, dtype=np.int64),
        lane_cp=lane_cp, lane_cp_s=lane_cp_s, lane_cp_other_lane=lane_cp_other_lane,
        lane_cp_other_s=lane_cp_other_s,
    )
