"""Shared pieces of the planned intersection modes (reservation, optimisation).

* :func:`next_crossing`: per vehicle, the next intersection it has not cleared yet, its conflict
  points and where it stops without permission (vectorised).
* :class:`PlanState`: per vehicle slot, the plan a vehicle follows through its next
  intersection (a target velocity), kept in step with the simulator's slots.
* :func:`plan_candidates`: trajectories "move to a cruise velocity at ``a_max``, then hold it"
  for a list of cruise velocities, with each one's occupancy of the conflict points and whether
  it keeps the same-lane invariant (``sim/safe_following.py``) against the leader's worst case.
* :func:`execute`: the acceleration every vehicle applies: its plan, or approach (free road,
  stop line when it holds no plan), always capped by the safe-following bound.

Occupancy: vehicle ``i`` occupies conflict point ``p`` at state index ``n`` (the state after
step ``n``) when ``|s_i(n) - s_p| < r_occ`` with ``r_occ = vehicle_length + margin``. Two
vehicles of crossing lanes whose occupancies of their shared point are disjoint are at least
``r_occ`` apart at every step (one of them is ``r_occ`` from the point), so they never collide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import safe_following as sf
from mivecc_env.sim.network import GridNetwork

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

#: Slack [m] kept by planned trajectories beyond the same-lane gap (float round-off).
PLAN_SLACK_M = 1e-6


def occupancy_radius_m(config: MiVeCCConfig) -> float:
    """Radius around a conflict point that one vehicle holds at a time [m]."""
    return config.vehicle_length_m + config.reservation_margin_m


@dataclass
class Crossing:
    """Next uncleared intersection of each vehicle (arrays of length n, view order)."""

    k: IntArray  # index of the intersection along the lane (lane_centres_s column)
    has: BoolArray  # False after the last intersection
    intersection: IntArray  # intersection id, -1 if none
    centre_s: FloatArray  # its centre on the lane [m]
    cp1_s: FloatArray  # first conflict point on the lane [m]
    cp2_s: FloatArray  # second conflict point [m]
    clear_s: FloatArray  # the vehicle has cleared the intersection from here on [m]
    stop_s: FloatArray  # farthest position allowed without a plan [m]


def next_crossing(network: GridNetwork, config: MiVeCCConfig, lane: IntArray,
                  s: FloatArray) -> Crossing:
    """The next intersection each vehicle has not cleared (vectorised)."""
    off, r = network.lane_offset_m, occupancy_radius_m(config)
    centres = network.lane_centres_s[lane]  # (n, n_on), inf padded
    k = np.sum(s[:, None] >= centres + off + r, axis=1)
    n_on = np.isfinite(network.lane_centres_s).sum(axis=1)[lane]
    has = k < n_on
    kk = np.minimum(k, network.lane_centres_s.shape[1] - 1)
    centre = np.where(has, centres[np.arange(lane.size), kk], np.inf)
    inter = np.where(has, network.lane_intersections[lane, kk], -1)
    return Crossing(k=k, has=has, intersection=inter, centre_s=centre, cp1_s=centre - off,
                    cp2_s=centre + off, clear_s=centre + off + r, stop_s=centre - off - r)


class PlanState:
    """Per vehicle slot: the intersection (lane column ``k``) a plan is for and its velocity."""

    def __init__(self, batch_size: int) -> None:
        self.batch_size = batch_size
        self.slot_vid = np.full((batch_size, 0), -1, dtype=np.int64)
        self.plan_k = np.full((batch_size, 0), -1, dtype=np.int64)
        self.plan_v = np.zeros((batch_size, 0))
        self.next_request = np.zeros((batch_size, 0), dtype=np.int64)
        self.refused = np.zeros((batch_size, 0), dtype=bool)

    def sync(self, vid: IntArray) -> None:
        """Follow the simulator's slots: grow with them, forget vehicles that left."""
        cap = vid.shape[1]
        if self.slot_vid.shape[1] < cap:
            pad = cap - self.slot_vid.shape[1]
            for name, fill in (("slot_vid", -1), ("plan_k", -1), ("plan_v", 0.0),
                               ("next_request", 0), ("refused", False)):
                arr = getattr(self, name)
                setattr(self, name, np.pad(arr, ((0, 0), (0, pad)), constant_values=fill))
        stale = self.slot_vid != vid
        if stale.any():
            self.slot_vid[stale] = vid[stale]
            self.plan_k[stale] = -1
            self.plan_v[stale] = 0.0
            self.next_request[stale] = 0
            self.refused[stale] = False


@dataclass
class Candidates:
    """Candidate trajectories of one vehicle (``n`` cruise velocities, ``H + 1`` states)."""

    v_cruise: FloatArray  # (n,)
    s: FloatArray  # (n, H + 1) positions [m]
    first: IntArray  # (n, 2) first state index occupying each conflict point
    last: IntArray  # (n, 2) last one
    ok: BoolArray  # (n,) clears the intersection in the horizon and keeps the same-lane gap


def cruise_grid(config: MiVeCCConfig, step_mps: float = 0.5) -> FloatArray:
    """Cruise velocities tried, fastest first [m/s]."""
    lo, hi = config.reservation_v_cross_min_mps, config.v_max_mps
    grid = np.arange(hi, lo - 1e-9, -step_mps)
    return grid if grid.size and grid[-1] == lo else np.append(grid, lo)


def plan_candidates(
    config: MiVeCCConfig, s0: float, v0: float, cp_s: tuple[float, float], clear_s: float,
    leader: tuple[float, float, float | None, float] | None, v_cruise: FloatArray,
) -> Candidates:
    """Candidate trajectories from (``s0``, ``v0``) through one intersection.

    Args:
        cp_s: the two conflict points on the lane [m].
        clear_s: position from which the intersection is cleared [m].
        leader: own-lane leader ``(s, v, plan velocity or None, release position)``; its
            worst case (:func:`safe_following.worst_case_leader`) is what the plans must keep
            the same-lane invariant against until they clear.
        v_cruise: cruise velocities to try [m/s].
    """
    b, dt = config.a_max_mps2, config.dt_s
    r = occupancy_radius_m(config)
    gap = config.vehicle_length_m + config.reservation_margin_m
    v_lo = float(np.min(v_cruise))
    horizon = int(np.ceil(max(clear_s - s0, 0.0) / (v_lo * dt))) + int(
        np.ceil(abs(v0 - v_lo) / (b * dt))) + 2
    u = sf.speed_profile(v0, v_cruise, horizon, b, dt)
    s = sf.positions(s0, u, dt)
    first = np.stack([np.argmax(s > p - r, axis=1) for p in cp_s], axis=1)
    last = np.stack([np.argmax(s >= p + r, axis=1) - 1 for p in cp_s], axis=1)
    ok = s[:, -1] >= clear_s
    if leader is not None:
        s_l, v_l, v_plan, release = leader
        s_w, u_w = sf.worst_case_leader(s_l, v_l, v_plan, release, horizon, b, dt)
        # The executed bound (ip.execute) assumes the leader brakes at b in every step, from
        # wherever it is: compare the plan's state n + 1 with one braking step from W(n).
        s_w1, u_w1 = sf.brake_step(s_w[:-1], u_w[:-1], b, dt)
        d_w1 = sf.stopping_point(s_w1, u_w1, b)
        d_f = sf.stopping_point(s[:, 1:], u[:, 1:], b)
        clear_j = np.argmax(s >= clear_s, axis=1)
        j = np.arange(1, horizon + 1)
        live = j[None, :] <= clear_j[:, None]
        bad = (s[:, 1:] > s_w1 - gap - PLAN_SLACK_M) | (d_f > d_w1 - gap - PLAN_SLACK_M)
        ok &= ~(bad & live).any(axis=1)
    return Candidates(v_cruise=np.asarray(v_cruise, dtype=np.float64), s=s, first=first,
                      last=last, ok=ok)


def execute(
    config: MiVeCCConfig, s: FloatArray, v: FloatArray, leader: IntArray, crossing: Crossing,
    planned: BoolArray, plan_v: FloatArray, approach_v: FloatArray,
    approach_brake: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Acceleration of every vehicle [m/s^2] and the acceleration its plan asked for.

    A vehicle with a plan for its next intersection moves towards ``plan_v``; one without
    moves towards ``approach_v`` (braking at most ``approach_brake``) and treats the point
    ``r_occ`` before the first conflict point as a standing obstacle; both are capped by the
    safe-following bound towards the own-lane leader. The result is clipped to ``>= -a_max``.
    """
    b, dt = config.a_max_mps2, config.dt_s
    gap = config.vehicle_length_m + config.reservation_margin_m
    target = np.where(planned, plan_v, approach_v)
    brake = np.where(planned, b, approach_brake)
    want = np.clip((target - v) / dt, -brake, b)
    has_l = leader >= 0
    li = np.maximum(leader, 0)
    s_obs = np.where(has_l, s[li], np.inf)
    v_obs = np.where(has_l, v[li], 0.0)
    a = np.minimum(want, sf.safe_accel(s, v, s_obs, v_obs, gap, b, dt))
    stop = crossing.has & ~planned
    s_line = np.where(stop, crossing.stop_s + gap, np.inf)
    a = np.minimum(a, sf.safe_accel(s, v, s_line, np.zeros_like(v), gap, b, dt))
    return a, want
