"""Signalized baseline: fixed-time signal heads and IDM car-following.

Each intersection runs a two-phase fixed-time plan: east-west green, yellow, all-red, then
north-south green, yellow, all-red (cycle ``2 (green + yellow + all_red)``), shifted by
``signal_offset_s * (row + col)`` (a simple green wave; 0 by default). A vehicle treats a red
head as a standing vehicle at the stop line; on yellow it stops if it can do so with the
comfortable deceleration, else it goes on. Car-following is the Intelligent Driver Model (IDM)
towards the nearer of the own-lane leader and a red stop line, with braking limited to
``idm_max_decel_mps2``. Velocity floor is 0. A vehicle enters only with room to stop behind a
standing vehicle (:func:`entry_clearance_m`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import step_kernels

if TYPE_CHECKING:
    from mivecc_env.sim.core import Simulator
    from mivecc_env.sim.virtual_lane import VirtualLaneView

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

GREEN, YELLOW, RED = 0, 1, 2


def phase_states(config: MiVeCCConfig, time_s: float | FloatArray) -> NDArray[np.int64]:
    """(n_intersections, 2) head state of the (east-west, north-south) approaches.

    ``time_s`` may be an array of clocks (one per environment): the result is then
    ``(*time_s.shape, n_intersections, 2)``.
    """
    g, y, r = config.signal_green_s, config.signal_yellow_s, config.signal_all_red_s
    half = g + y + r
    rows, cols = np.divmod(np.arange(config.n_intersections), config.cols)
    t = (np.asarray(time_s)[..., None] - config.signal_offset_s * (rows + cols)) % (2 * half)
    states = np.full((*t.shape, 2), RED, dtype=np.int64)
    for phase in (0, 1):
        local = t - phase * half
        states[..., phase] = np.where(
            (local >= 0) & (local < g), GREEN,
            np.where((local >= g) & (local < g + y), YELLOW, RED),
        )
    return states


def stop_line_offset_m(config: MiVeCCConfig) -> float:
    """Distance of the stop line before an intersection centre [m] (vehicle centre)."""
    return config.lane_offset_m + config.vehicle_length_m + 1.0


def idm_accel(
    v: FloatArray, gap_m: FloatArray, v_lead: FloatArray, config: MiVeCCConfig
) -> FloatArray:
    """IDM acceleration [m/s^2] towards a leader ``gap_m`` ahead (bumper to bumper)."""
    a, b = config.a_max_mps2, config.idm_comfort_decel_mps2
    s_star = config.idm_min_gap_m + np.maximum(
        0.0, v * config.idm_time_headway_s + v * (v - v_lead) / (2.0 * np.sqrt(a * b))
    )
    free = 1.0 - (v / config.v_max_mps) ** config.idm_delta
    interaction = (s_star / np.maximum(gap_m, 0.01)) ** 2
    return a * (free - np.where(np.isfinite(gap_m), interaction, 0.0))


def signalized_accel(
    sim: Simulator, view: VirtualLaneView, s: FloatArray, v: FloatArray
) -> FloatArray:
    """Acceleration of every vehicle of the view under signal control [m/s^2]."""
    c, net = sim.config, sim.network
    length = c.vehicle_length_m
    leader = view.leader
    gap_leader = np.where(leader >= 0, s[np.maximum(leader, 0)] - s - length, np.inf)
    v_leader = np.where(leader >= 0, v[np.maximum(leader, 0)], 0.0)
    a = idm_accel(v, gap_leader, v_leader, c)

    # Next stop line ahead on the vehicle's lane.
    stop_s = net.lane_centres_s[view.lane] - stop_line_offset_m(c)  # (n, n_on)
    ahead = stop_s > s[:, None] + 1e-9
    k = np.argmax(ahead, axis=1)
    has_stop = ahead.any(axis=1)
    n = s.size
    line = stop_s[np.arange(n), k]
    inter = net.lane_intersections[view.lane, k]
    phase = np.where(net.lane_horizontal[view.lane], 0, 1)
    state = sim.signal_phases.heads()[view.env, np.maximum(inter, 0), phase]
    dist = line - s
    can_stop = dist >= v * v / (2.0 * c.idm_comfort_decel_mps2)
    stop = has_stop & ((state == RED) | ((state == YELLOW) & can_stop))
    if c.signal_keep_clear:  # do not enter a box the vehicle may not leave
        asked = np.flatnonzero(has_stop & can_stop & ~stop)  # the others stop anyway or cannot
        stop[asked] = box_blocked(asked, s, v, leader, line[asked], c)
    a_line = idm_accel(v, np.where(stop, dist, np.inf), np.zeros_like(v), c)
    a = np.minimum(a, np.where(stop, a_line, np.inf))
    return np.clip(a, -c.idm_max_decel_mps2, c.a_max_mps2)


#: ``signal_keep_clear``: a vehicle slower than this [m/s] past its stop line stands in a queue.
QUEUED_MPS = 1.0
#: ... looked for this many vehicles ahead on the lane.
QUEUE_LOOKAHEAD = 12


def box_exit_m(line: FloatArray, c: MiVeCCConfig) -> FloatArray:
    """Where the box past each stop line ``line`` [m] ends [m]: the line mirrored past the
    intersection centre."""
    return line + 2.0 * stop_line_offset_m(c)


def box_blocked(asked: IntArray, s: FloatArray, v: FloatArray, leader: IntArray,
                line: FloatArray, c: MiVeCCConfig) -> NDArray[np.bool_]:
    """Whether each vehicle ``asked`` (indices into ``s``, ``v``, ``leader``; ``line``: its stop
    line [m]) lacks room on its lane past the box ahead (``signal_keep_clear``): the compiled
    kernel (``step_kernels.box_blocked``), or without numba :func:`box_blocked_reference`."""
    fast = step_kernels.box_blocked(asked, s, v, leader, line, box_exit_m(line, c),
                                    c.vehicle_length_m,
                                    c.vehicle_length_m + c.idm_min_gap_m, QUEUED_MPS,
                                    QUEUE_LOOKAHEAD)
    return box_blocked_reference(asked, s, v, leader, line, c) if fast is None else fast


def box_blocked_reference(asked: IntArray, s: FloatArray, v: FloatArray, leader: IntArray,
                          line: FloatArray, c: MiVeCCConfig) -> NDArray[np.bool_]:
    """:func:`box_blocked` in numpy (the reference of the compiled kernel).

    Along the vehicles ahead on its lane (up to :data:`QUEUE_LOOKAHEAD`), the first one past the
    vehicle's stop line that is slower than :data:`QUEUED_MPS` is the tail of a queue (one still
    before the line is discharging at this light and does not count). The vehicles before that
    tail will stop behind it; the lane is blocked when the room between the box exit (the stop
    line mirrored past the centre) and the tail's rear cannot take them and this vehicle, each
    ``vehicle_length_m + idm_min_gap_m``.
    """
    length, slot = c.vehicle_length_m, c.vehicle_length_m + c.idm_min_gap_m
    box_exit = box_exit_m(line, c)
    n = asked.size
    ahead = leader[asked]
    between = np.zeros(n, dtype=np.int64)
    tail_rear = np.full(n, np.inf)
    open_ = np.ones(n, dtype=bool)
    for _ in range(QUEUE_LOOKAHEAD):
        valid = open_ & (ahead >= 0)
        if not valid.any():  # every chain ended: at a queue's tail or the lane's first vehicle
            break
        k = np.maximum(ahead, 0)
        queued = valid & (s[k] >= line) & (v[k] < QUEUED_MPS)
        tail_rear = np.where(queued, s[k] - length, tail_rear)
        between += valid & ~queued
        open_ = valid & ~queued
        ahead = np.where(open_, leader[k], -1)
    return tail_rear - box_exit < (between + 1) * slot


def entry_clearance_m(config: MiVeCCConfig) -> float:
    """Entry clearance under the comparators [m] (``comparator_entry``): room to stop behind a
    standing vehicle from ``v_init`` (``"stop_clearance"``), or MiVeCC's ``entry_clearance_m``
    but at least the standstill gap plus a vehicle length (``"slowed"``, :func:`entry_speed`)."""
    standstill = config.idm_min_gap_m + config.vehicle_length_m
    if config.comparator_entry == "slowed":
        return max(config.entry_clearance_m, standstill)
    stop = config.v_init_mps**2 / (2.0 * config.idm_comfort_decel_mps2)
    return max(config.entry_clearance_m, stop + standstill)


def entry_speed(config: MiVeCCConfig, nearest_s: np.ndarray) -> np.ndarray:
    """Entry speed per lane [m/s] under ``comparator_entry="slowed"``: the speed from which a
    vehicle entering at ``s = 0`` stops at ``idm_comfort_decel`` a standstill gap behind the
    lane's nearest vehicle (at ``nearest_s`` [m]; inf: none), at most ``v_init``:
    ``min(v_init, sqrt(2 b (nearest_s - vehicle_length - idm_min_gap)))``."""
    room = np.maximum(nearest_s - config.vehicle_length_m - config.idm_min_gap_m, 0.0)
    return np.minimum(config.v_init_mps, np.sqrt(2.0 * config.idm_comfort_decel_mps2 * room))
