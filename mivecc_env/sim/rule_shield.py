"""A safety shield for the MiVeCC rules: safe following on every virtual lane (``safety_shield``).

Neither the paper nor the released code has this. The MiVeCC rules (end node, edge, cloud,
the released code's overrides) are not collision-free under the strict check (``docs/model.md``,
"The released model"); with ``safety_shield=True`` every vehicle's fused acceleration is capped
so that it keeps a Gipps-style invariant towards every point ahead of it on its own virtual
lane: its own-lane leader and each crossing vehicle projected onto the lane
(``sim/virtual_lane.py``). Vehicles cannot stop under unsignalized control (velocity floor
``v_min``), so the invariant of ``sim/safe_following.py`` is used in the frame that moves at
``v_min``: there every vehicle's velocity is ``u = v - v_min >= 0`` with floor 0, and a vehicle
that brakes at ``b = a_max`` reaches its *stopping point* ``s + u^2 / (2 b)`` of that frame.
Gaps are frame-independent, so the bound is :func:`safe_following.safe_accel` with ``u``.

Gap on a virtual lane: a crossing pair whose projected gap is ``g`` is at least ``g / sqrt 2``
apart (the two distances to the conflict point ``d1``, ``d2`` give ``sqrt(d1^2 + d2^2) >=
|d1 - d2| / sqrt 2``), so ``shield_gap_m >= sqrt 2 * vehicle_length_m`` (checked by the config)
keeps every pair that holds the invariant apart by more than ``vehicle_length_m``.

Every pair on a virtual lane is ordered the same way on both of its lanes (by signed distance
to the shared conflict point; a tie, which the view's sort leaves in construction order, goes to
the larger vehicle id), so exactly one of the two, the follower, keeps the invariant.
Once it holds, braking at ``b`` keeps it against any leader that brakes at most at ``b``. It can
be violated where braking cannot help: when a crossing vehicle first comes into view
(``projection_window_m`` before the conflict point) already too close, or when the released
code's speed reset lifts a velocity to ``v_max`` in one step. The follower then brakes at ``b``
and the vehicle ahead of it accelerates at ``a_max`` (as far as its own bound allows; where
that bound holds it back, the vehicle that sets it is pulled too, along the chain), which
restores the gap even when both are at ``v_min``, where braking alone cannot. Whether that
always suffices is measured, not assumed (``docs/model.md``, "A safety shield").
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import safe_following, shield_kernel
from mivecc_env.sim.virtual_lane import POSITION_RESOLUTION_M, VirtualLaneView

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Two points closer than this on a virtual lane are a tie [m] (the view's sort resolution).
TIE_M = POSITION_RESOLUTION_M


def horizon_m(config: MiVeCCConfig) -> float:
    """How far ahead [m] a point can constrain a vehicle: beyond it the invariant holds for any
    velocities (largest stopping-point lead ``(v_max - v_min)^2 / (2 a_max)``, one step at
    ``v_max`` and the gap)."""
    u_max = config.v_max_mps - config.v_min_mps
    return (u_max * u_max / (2.0 * config.a_max_mps2) + config.v_max_mps * config.dt_s
            + config.shield_gap_m)


def scan_reference(
    own: IntArray, run_start: IntArray, run_end: IntArray, point_pos: FloatArray,
    point_vehicle: IntArray, s: FloatArray, u: FloatArray, rank: IntArray, reach: float,
    tie: float, gap: float, b: float, dt: float,
) -> tuple[FloatArray, IntArray, NDArray[np.bool_]]:
    """Every vehicle's bound against the points ahead of it on its virtual lane (numpy path).

    Args:
        own: (n,) sorted index of each vehicle's own point; run_start / run_end: (P,) its
            group's first / one-past-last index; point_pos / point_vehicle: (P,) the view's.
        s: (n,) positions [m]; u: (n,) velocities above ``v_min`` [m/s]; rank: (n,) tie keys.
        reach: :func:`horizon_m` [m]; tie: :data:`TIE_M` [m]; gap [m]; b: ``a_max`` [m/s^2];
            dt [s].

    Returns (cap, binder, pulled): the bound [m/s^2] (``inf`` where none), the vehicle that
    gives it (-1), and the vehicles ahead in a pair whose bound is below ``-b``. Scans one
    point further along every lane per pass until no vehicle has a point within ``reach``
    left; points within ``tie`` of the vehicle count as ahead when their rank is larger (they
    may sit on either side of its own point, so ties are scanned backwards too).
    """
    n = own.size
    cap = np.full(n, np.inf)
    pulled = np.zeros(n, dtype=bool)
    binder = np.full(n, -1, dtype=np.int64)

    def bind(rows: IntArray, idx: IntArray, ahead: FloatArray) -> None:
        lead = point_vehicle[idx]
        keep = (ahead > tie) | (rank[lead] > rank[rows])  # ties: the larger key leads
        rows, idx, lead = rows[keep], idx[keep], lead[keep]
        bound = safe_following.safe_accel(s[rows], u[rows], point_pos[idx], u[lead], gap, b, dt)
        tighter = bound < cap[rows]
        cap[rows[tighter]] = bound[tighter]
        binder[rows[tighter]] = lead[tighter]
        pulled[lead[bound < -b]] = True

    for step, end, lo, hi in ((1, run_end[own], -np.inf, reach),
                              (-1, run_start[own] - 1, -tie, tie)):
        rows = np.arange(n)
        k = step
        while rows.size:
            idx = own[rows] + k
            inside = idx < end[rows] if step > 0 else idx > end[rows]
            rows, idx = rows[inside], idx[inside]
            ahead = point_pos[idx] - s[rows]
            near = (ahead <= hi) & (ahead >= lo)
            rows, idx, ahead = rows[near], idx[near], ahead[near]
            if rows.size:
                bind(rows, idx, ahead)
            k += step
    return cap, binder, pulled


def shield_bounds(
    view: VirtualLaneView, v: FloatArray, rank: IntArray, config: MiVeCCConfig
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Per view vehicle: the largest acceleration it may take [m/s^2] (``inf`` where
    unconstrained) and whether a follower needs it to pull away.

    Args:
        view: this step's virtual-lane view.
        v: (n,) velocities [m/s] in view order.
        rank: (n,) distinct keys of the vehicles of one environment (vehicle ids): of two
            points at the same position (within the view's sort resolution) the one with the
            larger key is ahead, on both virtual lanes of a crossing pair.
        config: ``v_min_mps``, ``a_max_mps2``, ``dt_s``, ``shield_gap_m``.

    The bound is the minimum of :func:`safe_following.safe_accel` over every point ahead of the
    vehicle on its own virtual lane within :func:`horizon_m`; it is below ``-a_max`` where the
    invariant is already violated. A vehicle is *pulled* when it is the point ahead in such a
    violated pair: its follower alone cannot restore the gap (both at ``v_min``, for instance,
    neither can slow down), so the leader accelerates; where its own bound keeps it from
    accelerating, the vehicle that gives that bound is pulled too, along the chain. The scan
    is :func:`shield_kernel.scan` (compiled) or :func:`scan_reference` (numpy), bit for bit
    the same.
    """
    n = view.n_vehicles
    if n == 0:
        return np.full(0, np.inf), np.zeros(0, dtype=bool)
    u = np.maximum(v - config.v_min_mps, 0.0)
    own = view.own_point
    args = (own, view.point_run_start, view.point_run_end, view.point_pos, view.point_vehicle,
            view.s, u, np.ascontiguousarray(rank, dtype=np.int64), horizon_m(config), TIE_M,
            config.shield_gap_m, config.a_max_mps2, config.dt_s)
    fast = shield_kernel.scan(*args)
    cap, binder, pulled = fast if fast is not None else scan_reference(*args)
    b = config.a_max_mps2
    # A pulled vehicle that its own bound keeps from accelerating pulls the vehicle that binds
    # it, and so on along the chain (each vehicle at most once).
    stuck = pulled & (cap < b) & (binder >= 0)
    while stuck.any():
        ahead_of = binder[stuck]
        fresh = ahead_of[~pulled[ahead_of]]
        pulled[fresh] = True
        stuck = np.zeros(n, dtype=bool)
        stuck[fresh] = True
        stuck &= (cap < b) & (binder >= 0)
    return cap, pulled


def apply_shield(
    accel: FloatArray, view: VirtualLaneView, v: FloatArray, rank: IntArray,
    config: MiVeCCConfig,
) -> FloatArray:
    """The fused accelerations [m/s^2] under the shield: a pulled vehicle takes ``+a_max``, then
    every vehicle is capped by its bound, never below ``-a_max`` through the cap (a vehicle that
    cannot keep the invariant brakes at ``a_max``); see :func:`shield_bounds`."""
    cap, pulled = shield_bounds(view, v, rank, config)
    wanted = np.where(pulled, config.a_max_mps2, accel)
    return np.minimum(wanted, np.maximum(cap, -config.a_max_mps2))
