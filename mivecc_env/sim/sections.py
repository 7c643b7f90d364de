"""Sections of the released code: where a vehicle is controlled, and what it sees there.

The released simulator cuts every through lane into sections, one per intersection it crosses:
section ``k`` runs from ``segment_length_m - section_after_m`` (140 m) before centre ``k`` to
``section_after_m`` (10 m) past it, so sections tile the lane; the first one reaches back to the
lane entry. A vehicle is *controlled* (rules, edge, cloud) while it is less than
``section_control_end_m`` (5 m) past its section's centre. Past that point, until the next
section starts, and on the whole exit link, it is *uncontrolled*:

* ``speed_reset=True`` (released code): it drives at ``v_max``, set instantly after each move
  (:func:`apply_speed_reset`);
* ``speed_reset=False``: it speeds up at ``+a_max`` within the velocity bounds
  (:func:`control_overrides`), the bounded counterpart of the reset.

With ``section_virtual_lanes=True`` a vehicle's virtual lane holds the controlled part of its
section only: own-lane vehicles there, and the vehicles of the two crossing lanes while they
are in the controlled part of the same intersection's section, projected at their conflict point
(so from up to 145 m before the point until 0-10 m past it). The opposite lane never crosses.
:func:`section_neighbours` builds this view with :func:`virtual_lane.build_view` on a derived
network whose lanes are the (lane, section) pairs.

Everything is vectorised over vehicles; nothing here changes the default model
(``sections=False``, ``section_virtual_lanes=False``, ``speed_reset=False``,
``header_rule=False``).
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


def section_of(
    network: GridNetwork, config: MiVeCCConfig, lane: IntArray, s: FloatArray
) -> tuple[IntArray, FloatArray]:
    """Section index along the lane (0-based) and the signed offset from its centre [m].

    ``offset = s - centre``: negative before the centre. Past the last section (exit link) the
    index is the last section's and the offset is ``>= section_after_m``.
    """
    seg = network.segment_length_m
    n_on = _sections_per_lane(network)[lane]
    k = np.floor((s + seg - config.section_after_m) / seg).astype(np.int64) - 1
    k = np.minimum(np.maximum(k, 0), n_on - 1)
    return k, s - network.lane_centres_s[lane, k]


def controlled(
    network: GridNetwork, config: MiVeCCConfig, lane: IntArray, s: FloatArray
) -> BoolArray:
    """True where a vehicle is in a section and less than ``section_control_end_m`` past its
    centre."""
    _, offset = section_of(network, config, lane, s)
    return offset < config.section_control_end_m


def distance_to_section_centre(
    network: GridNetwork, config: MiVeCCConfig, lane: IntArray, s: FloatArray
) -> FloatArray:
    """Distance still to go to the centre of the vehicle's section [m] (negative past it)."""
    _, offset = section_of(network, config, lane, s)
    return -offset


def control_area(
    network: GridNetwork, config: MiVeCCConfig, lane: IntArray, s: FloatArray
) -> IntArray:
    """Edge area (intersection id, -1 outside) of each point.

    ``sections=False``: :meth:`GridNetwork.control_area` (within ``control_radius_m`` of a
    centre). ``sections=True``: the intersection of the section whose controlled part holds the
    point (released code).
    """
    if not config.sections:
        return network.control_area(lane, s)
    k, offset = section_of(network, config, lane, s)
    return np.where(
        offset < config.section_control_end_m, network.lane_intersections[lane, k], -1
    )


def control_overrides(
    accel: FloatArray,
    is_controlled: BoolArray,
    d_front_m: FloatArray,
    config: MiVeCCConfig,
    seen: BoolArray | None = None,
) -> FloatArray:
    """Acceleration [m/s^2] after the released code's overrides, applied after all fusion.

    * ``header_rule``: a controlled vehicle with nothing ahead on its virtual lane
      (``d_front = inf``) gets ``+a_max``, whatever the rule, edge or cloud said;
    * ``sections``: an uncontrolled vehicle gets ``0`` under ``speed_reset`` (it already drives
      at ``v_max``; with ``stale_action`` it keeps ``accel``, its last action) and ``+a_max``
      otherwise.

    ``seen``: vehicles on a virtual lane this step (``stale_action``); only they can be headers.
    """
    a_max = config.a_max_mps2
    out = accel
    if config.header_rule:
        head = is_controlled & np.isinf(d_front_m)
        if seen is not None:
            head &= seen
        out = np.where(head, a_max, out)
    if config.sections or config.speed_reset:
        if not (config.speed_reset and config.stale_action):
            free = 0.0 if config.speed_reset else a_max
            out = np.where(is_controlled, out, free)
    return out


def stale_action(
    network: GridNetwork, config: MiVeCCConfig, view: VirtualLaneView, s: FloatArray,
    seen: BoolArray, a_end: FloatArray, sv: FloatArray, d_front_m: FloatArray,
    d_back_m: FloatArray, sv_last: FloatArray, closer_last: FloatArray,
    prev_s: tuple[IntArray, FloatArray] | None = None,
) -> FloatArray:
    """``a_end`` [m/s^2] with the released code's stale action (``stale_action=True``).

    A vehicle on a virtual lane this step (``seen``) records its SV and where its nearest
    vehicle is, as a distance to its section's centre (150 m with no neighbour, as there). One
    that is not acts on the recorded SV, judging the nearest vehicle ahead when that recorded
    distance is below its *current* distance to its (possibly new) section's centre, as the
    released code compares the two across sections. ``sv_last`` / ``closer_last``: flat
    per-slot records, updated in place.

    ``prev_s`` (``stale_corner_reset``): (flat slots, positions before the last move); a
    vehicle that entered the section of the south-east corner intersection in that move has
    its record set to 150 m first (:func:`corner_entries`), so unseen it acts on ``|SV/eta|``.
    """
    to_centre = distance_to_section_centre(network, config, view.lane, s)
    if prev_s is not None:
        closer_last[view.vehicle[corner_entries(network, config, view, s, prev_s)]] = 150.0
    ahead = d_front_m <= d_back_m
    closer_pos = np.where(ahead, s + d_front_m, s - d_back_m)
    closer = np.where(np.isfinite(np.minimum(d_front_m, d_back_m)),
                      to_centre - (closer_pos - s), 150.0)
    slots = view.vehicle
    sv_last[slots[seen]] = sv[seen]
    closer_last[slots[seen]] = closer[seen]
    ratio = sv_last[slots] / config.eta
    stale = np.where(closer_last[slots] < to_centre, ratio, np.abs(ratio))
    return np.where(seen, a_end, stale)


def corner_intersection(network: GridNetwork) -> int:
    """Id of the south-east corner intersection (largest x, smallest y): the released code's
    section 8 on its 3x3 grid."""
    x, y = network.intersection_xy[:, 0], network.intersection_xy[:, 1]
    return int(np.lexsort((-x, y))[0])


def corner_entries(
    network: GridNetwork, config: MiVeCCConfig, view: VirtualLaneView, s: FloatArray,
    prev_s: tuple[IntArray, FloatArray],
) -> BoolArray:
    """(n,) view vehicles that entered the corner intersection's section in the last move
    (``prev_s`` = flat slots and positions before it; vehicles not in it had just entered the
    network and are left out)."""
    slots, s_old = prev_s
    before = np.full(view.lane.size, -1, dtype=np.int64)
    known = np.isin(view.vehicle, slots)
    if known.any():
        where = np.searchsorted(slots, view.vehicle[known])
        before[known] = section_of(network, config, view.lane[known], s_old[where])[0]
    k, _ = section_of(network, config, view.lane, s)
    corner = network.lane_intersections[view.lane, k] == corner_intersection(network)
    return known & (before != k) & corner


def apply_speed_reset(
    network: GridNetwork, config: MiVeCCConfig, lane: IntArray, s_new: FloatArray,
    v_new: FloatArray,
) -> FloatArray:
    """Velocities after the released code's speed reset: ``v_max`` for every vehicle that is
    uncontrolled after its move (an instant jump, not bounded by ``a_max``)."""
    free = ~controlled(network, config, lane, s_new)
    return np.where(free, config.v_max_mps, v_new)


# ------------------------------------------------------------------------------------------
# section-limited virtual lanes
def _sections_per_lane(network: GridNetwork) -> IntArray:
    return np.isfinite(network.lane_centres_s).sum(axis=1)


@functools.lru_cache(maxsize=32)
def _section_network(
    rows: int, cols: int, seg: float, off: float, radius: float
) -> GridNetwork:
    """A derived network whose lane ``l * n_on_max + k`` is section ``k`` of lane ``l``.

    Each derived lane keeps the positions of its lane (``s`` from the lane entry) and only the
    two conflict points of its own intersection, whose crossing lanes are the derived lanes of
    the same intersection's sections.
    """
    net = build_grid(rows, cols, seg, off, radius)
    n_on_max = net.lane_centres_s.shape[1]
    n = net.n_lanes * n_on_max
    cp_s = np.full((n, 2), np.inf)
    other_lane = np.full((n, 2), -1, dtype=np.int64)
    other_s = np.full((n, 2), np.inf)
    centres = np.full((n, 1), np.inf)
    # section index of each intersection on each lane
    sec_of = np.full((net.n_lanes, net.n_intersections), -1, dtype=np.int64)
    for lane in range(net.n_lanes):
        for k, i in enumerate(net.lane_intersections[lane]):
            if i >= 0:
                sec_of[lane, i] = k
    for lane in range(net.n_lanes):
        for k, i in enumerate(net.lane_intersections[lane]):
            if i < 0:
                continue
            d = lane * n_on_max + k
            centres[d, 0] = net.lane_centres_s[lane, k]
            cols_ = np.flatnonzero(net.cp_intersection[np.maximum(net.lane_cp[lane], 0)] == i)
            cols_ = cols_[net.lane_cp[lane, cols_] >= 0]
            for j, col in enumerate(cols_[:2]):
                m = net.lane_cp_other_lane[lane, col]
                cp_s[d, j] = net.lane_cp_s[lane, col]
                other_lane[d, j] = m * n_on_max + sec_of[m, i]
                other_s[d, j] = net.lane_cp_other_s[lane, col]
    return dataclasses.replace(
        net, n_lanes=n, lane_centres_s=centres, lane_cp_s=cp_s, lane_cp_other_lane=other_lane,
        lane_cp_other_s=other_s,
    )


def section_view(
    network: GridNetwork, config: MiVeCCConfig, active: BoolArray, lane: IntArray, s: FloatArray,
    prev_s: tuple[IntArray, FloatArray] | None = None,
) -> VirtualLaneView:
    """The section-limited virtual-lane view of the controlled vehicles (see the module doc).

    Lanes of the returned view are derived lanes ``lane * n_on_max + section``. With
    ``section_entry_lag``, ``prev_s`` = (flat slots, positions before the last move) leaves out
    the vehicles whose section changed in that move and those that just entered (``s = 0``).
    """
    net = _section_network(
        network.rows, network.cols, network.segment_length_m, network.lane_offset_m,
        network.control_radius_m,
    )
    n_on_max = network.lane_centres_s.shape[1]
    flat = np.flatnonzero(active)
    lane_f, s_f = lane.ravel()[flat], s.ravel()[flat]
    k, offset = section_of(network, config, lane_f, s_f)
    keep = offset < config.section_control_end_m
    if config.section_entry_lag:
        keep &= s_f > 0.0  # entered at the end of the last step: not seen yet
        if prev_s is not None and prev_s[0].size:
            before = np.full(active.size, -1, dtype=np.int64)
            slots, s_old = prev_s
            before[slots] = section_of(network, config, lane.ravel()[slots], s_old)[0]
            k_old = before[flat]
            keep &= (k_old < 0) | (k_old == k)  # -1: no record (a slot filled this step)
    sec_active = np.zeros(active.size, dtype=bool)
    sec_active[flat[keep]] = True
    sec_lane = np.zeros(active.size, dtype=np.int64)
    sec_lane[flat] = lane_f * n_on_max + k
    # Crossing vehicles are members only while controlled, so the window never cuts them:
    # from the lane entry (up to a segment plus the offset before the point) to the end of
    # the controlled part (control end plus the offset past the point).
    window = network.segment_length_m + network.lane_offset_m + 1.0
    clear = config.section_control_end_m + network.lane_offset_m
    return build_view(
        net, window, clear, sec_active.reshape(active.shape), sec_lane.reshape(active.shape), s
    )


def section_neighbours(
    network: GridNetwork, config: MiVeCCConfig, view: VirtualLaneView, active: BoolArray,
    lane: IntArray, s: FloatArray, prev_s: tuple[IntArray, FloatArray] | None = None,
) -> tuple[IntArray, IntArray, FloatArray, FloatArray, BoolArray]:
    """Nearest vehicle ahead / behind on each vehicle's section-limited virtual lane.

    Returns ``(front, back, d_front, d_back, member)`` in the order of ``view`` (the full
    view): indices into ``view``'s vehicles (-1 if none), distances [m] (``inf`` if none) and
    whether the vehicle is on a section virtual lane at all. Uncontrolled vehicles are not.
    """
    sec = section_view(network, config, active, lane, s, prev_s)
    n = view.n_vehicles
    front = np.full(n, -1, dtype=np.int64)
    back = np.full(n, -1, dtype=np.int64)
    d_front = np.full(n, np.inf)
    d_back = np.full(n, np.inf)
    member = np.zeros(n, dtype=bool)
    if sec.n_vehicles == 0:
        return front, back, d_front, d_back, member
    # Both views list vehicles in increasing flat slot order.
    to_main = np.searchsorted(view.vehicle, sec.vehicle)
    pv = to_main[sec.point_vehicle]
    front[to_main] = np.where(sec.front_point >= 0, pv[np.maximum(sec.front_point, 0)], -1)
    back[to_main] = np.where(sec.back_point >= 0, pv[np.maximum(sec.back_point, 0)], -1)
    d_front[to_main] = sec.d_front
    d_back[to_main] = sec.d_back
    member[to_main] = True
    return front, back, d_front, d_back, member
