"""The cloud's view under the released model: its virtual lanes and its reward population.

By default (``cloud_view="window"``) the cloud reads the same windowed virtual-lane view as
the edges (``projection_window_m`` before a conflict point to ``projection_clear_m`` past it).
The released code builds its cloud graph from a second, network-wide view
(``cloud_view="released"``, :func:`released_cloud_view`): the virtual lane of through lane
``l`` holds

* its own vehicles before its last intersection centre ``c_last(l)``, and
* every vehicle of every lane ``m`` crossing ``l``, projected at their conflict point
  (``s_cp(l) + s - s_cp(m)``) from the entry of ``m`` (its whole upstream part) until
  ``lane_offset_m`` past the point, and only where the projection lands before
  ``c_last(l)``. So at a conflict point past ``c_last(l)`` (the last centre plus the lane
  offset) a crossing vehicle is seen until ``lane_offset_m`` *before* the point.

Projections can land before the entry of ``l`` (negative positions: the crossing lane's
upstream part is longer than the ego lane's part before the point). The view is built with
:func:`virtual_lane.build_view` on a derived network (the pattern of
:mod:`mivecc_env.sim.sections`): lanes ``0..L-1`` hold the vehicles before their last centre,
lanes ``L..2L-1`` the others (own points in groups nobody reads; their projections count), and
each conflict point whose projection would cross ``c_last`` is shifted on both lanes so that
one clear distance serves every point. It lists the same vehicles in the same order as the
simulator's view (every active vehicle, increasing flat slot), so per-vehicle arrays of that
view (velocity, acceleration, pick population) index it unchanged, and decisions map back to
slots through ``view.vehicle``.

The cloud's velocity reward under ``cloud_reward_population="released"``
(:func:`reward_population`) counts the released code's *controlled* vehicles: from their first
move until the step after the one in which they passed ``section_control_end_m`` (5 m) beyond
their lane's last centre (the released code counts a vehicle once more on the update at which
it marks it finished). Nothing here runs under the default model.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.network import GridNetwork, build_grid
from mivecc_env.sim.virtual_lane import VirtualLaneView, build_view

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


def last_centre_s(network: GridNetwork) -> FloatArray:
    """(n_lanes,) distance of each lane's last intersection centre from its entry [m]."""
    c = network.lane_centres_s
    return np.where(np.isfinite(c), c, -np.inf).max(axis=1)


@functools.lru_cache(maxsize=32)
def _cloud_network(rows: int, cols: int, seg: float, off: float, radius: float) -> GridNetwork:
    """Derived network of :func:`released_cloud_view`: lanes ``l`` and ``l + L`` both cross
    the real lanes; conflict coordinates shifted where a projection would pass ``c_last``."""
    net = build_grid(rows, cols, seg, off, radius)
    n = net.n_lanes
    other, other_s = net.lane_cp_other_lane, net.lane_cp_other_s
    real = other >= 0
    # Largest offset past the point that still lands before the other lane's last centre.
    room = np.where(real, last_centre_s(net)[np.maximum(other, 0)] - other_s, off)
    shift = np.where(real, np.maximum(off - room, 0.0), 0.0)

    def twice(x: np.ndarray) -> np.ndarray:
        return np.concatenate([x, x])

    return dataclasses.replace(
        net, n_lanes=2 * n, lane_length=twice(net.lane_length),
        lane_origin=twice(net.lane_origin), lane_dir=twice(net.lane_dir),
        lane_horizontal=twice(net.lane_horizontal), lane_heading=twice(net.lane_heading),
        lane_centres_s=twice(net.lane_centres_s),
        lane_intersections=twice(net.lane_intersections), lane_cp=twice(net.lane_cp),
        lane_cp_s=twice(net.lane_cp_s - shift), lane_cp_other_lane=twice(other),
        lane_cp_other_s=twice(other_s - shift),
    )


def released_cloud_view(
    network: GridNetwork, active: BoolArray, lane: IntArray, s: FloatArray
) -> VirtualLaneView:
    """The released code's cloud view of a batch (module doc); ``lane`` of the result is the
    real through lane of each vehicle.

    Args:
        active / lane / s: (B, capacity) the simulator's slot arrays (``s`` [m]).
    """
    net = _cloud_network(network.rows, network.cols, network.segment_length_m,
                         network.lane_offset_m, network.control_radius_m)
    n = network.n_lanes
    past = s >= last_centre_s(network)[lane]
    cloud_lane = np.where(past, lane + n, lane)
    window = float(network.lane_length.max()) + network.lane_offset_m + 1.0
    view = build_view(net, window, network.lane_offset_m, active, cloud_lane, s)
    return dataclasses.replace(view, lane=view.lane % n)


def cloud_virtual_lanes(
    network: GridNetwork, config: MiVeCCConfig, view: VirtualLaneView, active: BoolArray,
    lane: IntArray, s: FloatArray,
) -> VirtualLaneView:
    """The view the cloud reads: ``view`` itself (``cloud_view="window"``) or
    :func:`released_cloud_view` (same vehicles, same order)."""
    if config.cloud_view == "window":
        return view
    return released_cloud_view(network, active, lane, s)


def reward_population(
    network: GridNetwork, config: MiVeCCConfig, view: VirtualLaneView, picks: BoolArray,
    prev_s: tuple[IntArray, FloatArray] | None,
) -> BoolArray:
    """(n,) view vehicles of the cloud's velocity reward.

    ``cloud_reward_population="picks"``: ``picks`` (the pick population). ``"released"``: the
    vehicles that have moved (``s > 0``) and whose position before the last move was at most
    ``section_control_end_m`` past their lane's last centre.

    Args:
        prev_s: (flat slots in increasing order, positions [m]) before the last move
            (:attr:`Simulator.prev_positions`); None before the first step (nobody counts).
    """
    if config.cloud_reward_population == "picks":
        return picks
    limit = last_centre_s(network)[view.lane] + config.section_control_end_m
    before = np.full(view.n_vehicles, np.inf)
    if prev_s is not None and prev_s[0].size:
        slots, s_old = prev_s
        at = np.minimum(np.searchsorted(slots, view.vehicle), slots.size - 1)
        known = slots[at] == view.vehicle
        before[known] = s_old[at[known]]
    return (view.s > 0.0) & (before <= limit)
