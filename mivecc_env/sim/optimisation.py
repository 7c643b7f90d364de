"""DOOC-style arrival-time optimisation (after Bian et al., IEEE TIE 2020).

``control="optimisation"``.

Bian et al. split cooperative passing into *state observation*, *arrival-time optimisation* and
*trajectory tracking*. Here, per intersection and every ``optimisation_period_s``:

1. **Observation**: the vehicles within ``control_radius_m`` of the intersection centre that
   have not cleared it; the ``optimisation_max_vehicles`` nearest are scheduled. Vehicles that
   can no longer stop before the conflict zone (committed) keep their plan; their predicted
   arrival is a fixed input.
2. **Arrival-time optimisation** (:func:`schedule_milp`, a MILP solved by HiGHS through
   ``scipy.optimize.milp``): choose each vehicle's arrival time ``t_i`` at the intersection
   centre, minimising the total delay ``sum(t_i - earliest_i)`` subject to
   ``earliest_i <= t_i <= latest_i`` (the kinematic bounds: the earliest arrival accelerates at
   ``a_max`` to ``v_max``, the latest decelerates to ``reservation_v_cross_min_mps``), the
   lane order with headway ``t_next >= t_prev + h`` and, for every pair of crossing lanes,
   ``|t_i - t_j| >= h`` (a binary per pair) with ``h = optimisation_headway_s``.
3. **Trajectory tracking**: each vehicle takes the fastest "move to a cruise velocity at
   ``a_max``, hold it" trajectory (the reservation mode's family) that arrives no earlier than
   its ``t_i``; the same-lane safe-following bound (``sim/safe_following.py``) caps it.
   Vehicles without a schedule stop before the conflict zone.

Unlike the reservation mode nothing here is checked against the exact trajectories: the
headway at the centre stands in for the conflict points' occupancy, and tracking can lag a
schedule. Collisions are therefore possible and counted (``docs/comparators.md`` reports them
by density).
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import intersection_plan as ip
from mivecc_env.sim import safe_following as sf
from mivecc_env.sim.network import GridNetwork

if TYPE_CHECKING:
    from mivecc_env.sim.core import Simulator
    from mivecc_env.sim.virtual_lane import VirtualLaneView

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


# ----------------------------------------------------------------------------------------
# the scheduling problem
def _pairs(lane: IntArray, horizontal: BoolArray) -> tuple[list, list]:
    """Same-lane (leader, follower) pairs (array order = lane order) and crossing pairs."""
    n = lane.size
    same, cross = [], []
    for i in range(n):
        for j in range(i + 1, n):
            if lane[i] == lane[j]:
                same.append((i, j))
            elif horizontal[i] != horizontal[j]:
                cross.append((i, j))
    return same, cross


def schedule_milp(
    earliest: FloatArray, latest: FloatArray, lane: IntArray, horizontal: BoolArray,
    headway_s: float, fixed: FloatArray | None = None,
) -> FloatArray:
    """Arrival times [s] minimising ``sum(t - earliest)`` (see module docstring).

    Args:
        earliest, latest: (n,) bounds of each vehicle's arrival time [s].
        lane: (n,) lane of each vehicle; vehicles of one lane are given in lane order.
        horizontal: (n,) True for east/westbound lanes (they cross the others).
        headway_s: minimum time between crossing-lane and between same-lane arrivals [s].
        fixed: (n,) arrival time of committed vehicles, NaN for the free ones.

    Returns:
        (n,) arrival times. If the bounds make the problem infeasible the upper bounds are
        dropped (a vehicle may then be scheduled later than its slowest trajectory).
    """
    from scipy.optimize import Bounds, LinearConstraint, milp

    n = earliest.size
    if n == 0:
        return np.zeros(0)
    fixed = np.full(n, np.nan) if fixed is None else np.asarray(fixed, dtype=np.float64)
    is_fixed = ~np.isnan(fixed)
    same, cross = _pairs(np.asarray(lane), np.asarray(horizontal))
    lo = np.where(is_fixed, fixed, earliest)
    # Times are searched up to ``cap``: the earliest-first greedy schedule fits below it.
    cap = float(np.max(lo) + headway_s * (n + 1))
    for upper in (np.minimum(latest, cap), np.full(n, cap)):
        hi = np.where(is_fixed, fixed, np.maximum(upper, earliest))
        x = _solve(lo, hi, same, cross, headway_s, milp, Bounds, LinearConstraint)
        if x is not None:
            return x
    # committed vehicles may already violate a headway: schedule the free ones greedily
    return greedy_times(np.argsort(np.where(is_fixed, -np.inf, earliest), kind="stable"),
                        np.where(is_fixed, fixed, earliest), lane, horizontal, headway_s,
                        is_fixed)


def _solve(lo: FloatArray, hi: FloatArray, same: list, cross: list, h: float, milp: Any,
           bounds_cls: Any, constraint_cls: Any) -> FloatArray | None:
    """One MILP with per-pair big-M constants; None if infeasible."""
    n = lo.size
    rows, lb = [], []
    for i, j in same:  # t_j - t_i >= h
        r = np.zeros(n)
        r[j], r[i] = 1.0, -1.0
        rows.append(r)
        lb.append(h)
    free = []
    for i, j in cross:
        if lo[j] >= hi[i] + h:  # i is first whatever the choice
            continue
        if lo[i] >= hi[j] + h:
            continue
        free.append((i, j))
    m = len(free)
    rows = [np.r_[r, np.zeros(m)] for r in rows]
    for k, (i, j) in enumerate(free):
        # y = 1: i first (t_j - t_i >= h); y = 0: j first (t_i - t_j >= h)
        m_ij = h + hi[i] - lo[j]
        m_ji = h + hi[j] - lo[i]
        r = np.zeros(n + m)
        r[j], r[i], r[n + k] = 1.0, -1.0, -m_ij
        rows.append(r)
        lb.append(h - m_ij)
        r = np.zeros(n + m)
        r[i], r[j], r[n + k] = 1.0, -1.0, m_ji
        rows.append(r)
        lb.append(h)
    cost = np.r_[np.ones(n), np.zeros(m)]
    integrality = np.r_[np.zeros(n), np.ones(m)]
    bounds = bounds_cls(np.r_[lo, np.zeros(m)], np.r_[hi, np.ones(m)])
    cons = [constraint_cls(np.array(rows), lb, np.inf)] if rows else []
    res = milp(cost, constraints=cons, integrality=integrality, bounds=bounds)
    return np.asarray(res.x[:n]) if res.status == 0 else None


def greedy_times(order: IntArray, earliest: FloatArray, lane: IntArray, horizontal: BoolArray,
                 headway_s: float, keep: BoolArray | None = None) -> FloatArray:
    """Earliest times for a service order: each vehicle as soon as its bounds allow.

    For a fixed order this is the optimum of the scheduling problem without upper bounds (each
    time is the smallest value its lower bounds allow). ``keep`` marks times not to change.
    """
    t = np.asarray(earliest, dtype=np.float64).copy()
    keep = np.zeros(t.size, dtype=bool) if keep is None else keep
    done: list[int] = []
    for i in order:
        if not keep[i]:
            for j in done:
                if lane[j] == lane[i] or horizontal[j] != horizontal[i]:
                    t[i] = max(t[i], t[j] + headway_s)
        done.append(int(i))
    return t


def schedule_brute_force(earliest: FloatArray, latest: FloatArray, lane: IntArray,
                         horizontal: BoolArray, headway_s: float) -> tuple[float, FloatArray]:
    """Optimal total delay by trying every service order that keeps the lane orders (tiny n)."""
    n = earliest.size
    best, best_t = np.inf, np.zeros(n)
    for perm in itertools.permutations(range(n)):
        pos = np.empty(n, dtype=np.int64)
        pos[list(perm)] = np.arange(n)
        if any(lane[i] == lane[j] and pos[i] > pos[j] for i in range(n) for j in range(i + 1, n)):
            continue
        t = greedy_times(np.array(perm), earliest, lane, horizontal, headway_s)
        if np.any(t > latest + 1e-9):
            continue
        cost = float(np.sum(t - earliest))
        if cost < best - 1e-12:
            best, best_t = cost, t
    return best, best_t


def check_schedule(t: FloatArray, earliest: FloatArray, latest: FloatArray, lane: IntArray,
                   horizontal: BoolArray, headway_s: float, tol: float = 1e-6) -> list[str]:
    """Violations of a schedule (empty when feasible)."""
    bad = []
    same, cross = _pairs(np.asarray(lane), np.asarray(horizontal))
    for i in range(t.size):
        if t[i] < earliest[i] - tol or t[i] > latest[i] + tol:
            bad.append(f"vehicle {i}: {t[i]} outside [{earliest[i]}, {latest[i]}]")
    for i, j in same:
        if t[j] - t[i] < headway_s - tol:
            bad.append(f"same lane {i}->{j}: {t[j] - t[i]}")
    for i, j in cross:
        if abs(t[j] - t[i]) < headway_s - tol:
            bad.append(f"crossing {i},{j}: {abs(t[j] - t[i])}")
    return bad


def arrival_time_s(d: FloatArray, v0: FloatArray, v_c: FloatArray, b: float) -> FloatArray:
    """Time [s] to cover ``d`` moving from ``v0`` to ``v_c`` at ``b`` then holding ``v_c``."""
    d, v0, v_c = np.broadcast_arrays(np.asarray(d, float), np.asarray(v0, float),
                                     np.asarray(v_c, float))
    t_ch = np.abs(v_c - v0) / b
    d_ch = 0.5 * (v0 + v_c) * t_ch
    acc = np.where(v_c >= v0, b, -b)
    # within the speed change: d = v0 t + acc t^2 / 2
    disc = np.maximum(v0 * v0 + 2.0 * acc * d, 0.0)
    t_in = np.where(np.abs(acc) > 0, (-v0 + np.sqrt(disc)) / acc, d / np.maximum(v0, 1e-9))
    t_out = t_ch + (d - d_ch) / np.maximum(v_c, 1e-9)
    return np.where(d <= d_ch, t_in, t_out)


def slow_then_sprint_time_s(d_m: FloatArray, v0: FloatArray, v_c: FloatArray, v_max: float,
                            b: float) -> FloatArray:
    """Time [s] to cover ``d_m``: move to ``v_c`` at ``b``, hold it, then accelerate at ``b``
    so as to reach ``v_max`` exactly at ``d_m``. NaN where the distance is too short for it."""
    d_m, v0, v_c = np.broadcast_arrays(np.asarray(d_m, float), np.asarray(v0, float),
                                       np.asarray(v_c, float))
    t_ch = np.abs(v_c - v0) / b
    d_ch = 0.5 * (v0 + v_c) * t_ch
    t_up = (v_max - v_c) / b
    d_up = 0.5 * (v_c + v_max) * t_up
    hold = d_m - d_ch - d_up
    t = t_ch + hold / np.maximum(v_c, 1e-9) + t_up
    return np.where(hold >= 0.0, t, np.nan)


# ----------------------------------------------------------------------------------------
class OptimisationControl:
    """The optimisation control mode of a :class:`Simulator` (see module docstring)."""

    def __init__(self, config: MiVeCCConfig, network: GridNetwork, batch_size: int) -> None:
        self.config = config
        self.network = network
        self.batch_size = batch_size
        self.cruise = ip.cruise_grid(config, step_mps=0.1)
        self.period = max(1, round(config.optimisation_period_s / config.dt_s))
        self.reset()

    def reset(self) -> None:
        self.plans = ip.PlanState(self.batch_size)
        self.solves = 0
        self.deviations = 0

    def accel(self, sim: Simulator, view: VirtualLaneView, s: FloatArray,
              v: FloatArray) -> FloatArray:
        """Acceleration of every vehicle [m/s^2]; re-solves the schedules every period."""
        c = self.config
        self.plans.sync(sim.vid)
        crossing = ip.next_crossing(self.network, c, view.lane, s)
        if sim.step_count % self.period == 0:
            self._solve_all(view, s, v, crossing)
        flat = view.vehicle
        planned = crossing.has & (self.plans.plan_k.ravel()[flat] == crossing.k)
        approach_v = np.full(s.shape, c.v_max_mps)
        brake = np.full(s.shape, c.a_max_mps2)
        # tracking: hold the planned velocity, sprint to v_max over the last stretch before
        # the first conflict point (so that the conflict zone is crossed fast)
        sprint = (crossing.cp1_s - s) <= (c.v_max_mps**2 - v * v) / (2.0 * c.a_max_mps2) + (
            v * c.dt_s)
        target = np.where(sprint, c.v_max_mps, self.plans.plan_v.ravel()[flat])
        a, want = ip.execute(c, s, v, view.leader, crossing, planned, target, approach_v, brake)
        self.deviations += int(np.sum(planned & (a < want - 1e-6)))
        return np.maximum(a, -c.a_max_mps2)

    def _solve_all(self, view: VirtualLaneView, s: FloatArray, v: FloatArray,
                   crossing: ip.Crossing) -> None:
        c, net = self.config, self.network
        b = c.a_max_mps2
        near = crossing.has & (crossing.centre_s - s <= c.control_radius_m)
        idx = np.flatnonzero(near)
        if idx.size == 0:
            return
        key = view.env[idx] * net.n_intersections + crossing.intersection[idx]
        order = np.lexsort((crossing.centre_s[idx] - s[idx], key))
        idx, key = idx[order], key[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        ends = np.r_[starts[1:], idx.size]
        flat = view.vehicle
        plan_k, plan_v = self.plans.plan_k.ravel(), self.plans.plan_v.ravel()
        for a0, a1 in zip(starts, ends, strict=True):
            overflow = flat[idx[a0:a1][c.optimisation_max_vehicles:]]
            plan_k[overflow] = -1  # farther than the scheduled ones: they wait for a schedule
            group = idx[a0:a1][: c.optimisation_max_vehicles]
            dist = crossing.centre_s[group] - s[group]
            planned = plan_k[flat[group]] == crossing.k[group]
            stop_d = sf.stopping_point(s[group], v[group], b)
            committed = (s[group] > crossing.stop_s[group]) | (
                stop_d > crossing.stop_s[group] + 1e-9)
            committed &= planned
            v_plan = np.where(planned, plan_v[flat[group]], v[group])
            v_max, off = c.v_max_mps, net.lane_offset_m
            d_cp1 = np.maximum(dist - off, 0.0)
            after = off / v_max  # from the first conflict point to the centre at v_max
            fixed_t = slow_then_sprint_time_s(d_cp1, v[group], np.maximum(v_plan, 0.5), v_max, b)
            fixed_t = np.where(np.isnan(fixed_t), arrival_time_s(d_cp1, v[group], v_max, b),
                               fixed_t) + after
            fixed = np.where(committed, fixed_t, np.nan)
            t_grid = slow_then_sprint_time_s(d_cp1[:, None], v[group][:, None],
                                             self.cruise[None, :], v_max, b) + after
            t_grid[:, 0] = arrival_time_s(d_cp1, v[group], v_max, b) + after
            earliest, latest = t_grid[:, 0], np.nanmax(t_grid, axis=1)
            lanes = view.lane[group]
            t = schedule_milp(earliest, latest, lanes, net.lane_horizontal[lanes],
                              c.optimisation_headway_s, fixed)
            self.solves += 1
            # fastest cruise velocity arriving no earlier than the schedule
            late_enough = np.nan_to_num(t_grid, nan=-np.inf) >= (t[:, None] - 0.5 * c.dt_s)
            pick = np.where(late_enough.any(axis=1), np.argmax(late_enough, axis=1),
                            self.cruise.size - 1)
            free = ~committed
            slots = flat[group][free]
            plan_k[slots] = crossing.k[group][free]
            plan_v[slots] = self.cruise[pick[free]]
