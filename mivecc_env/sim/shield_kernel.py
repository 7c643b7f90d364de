"""Compiled scan of the safety shield (``sim/rule_shield.py``): one pass per vehicle.

:func:`scan` gives, bit for bit, the bounds, binders and pulls of the numpy reference
:func:`mivecc_env.sim.rule_shield.scan_reference` (same arithmetic in the same order as
:func:`mivecc_env.sim.safe_following.safe_accel`, no fast-math); None without numba.
"""

from __future__ import annotations

import math

import numpy as np

from mivecc_env.sim._numba import HAVE_NUMBA, njit


@njit
def _safe_accel(s, u, s_obs, u_obs, gap, b, dt):  # pragma: no cover - compiled
    a_o = max(-b, -u_obs / dt)
    s_o1 = s_obs + u_obs * dt + 0.5 * a_o * dt * dt
    u_o1 = max(u_obs + a_o * dt, 0.0)
    d_o1 = s_o1 + u_o1 * u_o1 / (2.0 * b)
    a_pos = 2.0 * (s_o1 - gap - s - u * dt) / (dt * dt)
    c = s + 0.5 * u * dt - (d_o1 - gap)
    disc = 0.25 * dt * dt - 2.0 * c / b
    if disc >= 0.0:
        u1 = b * (-0.5 * dt + math.sqrt(max(disc, 0.0)))
        a_stop = (u1 - u) / dt
    else:
        a_stop = -np.inf
    return min(a_pos, a_stop)


@njit
def _bind(i, j, lead, point_pos, s, u, gap, b, dt, cap, binder, pulled):  # pragma: no cover
    """Vehicle ``i`` against point ``j`` (vehicle ``lead``) ahead of it."""
    bound = _safe_accel(s[i], u[i], point_pos[j], u[lead], gap, b, dt)
    if bound < cap[i]:
        cap[i] = bound
        binder[i] = lead
    if bound < -b:
        pulled[lead] = True


@njit
def _scan(own, run_start, run_end, point_pos, point_vehicle, s, u, rank, reach, tie, gap, b,
          dt, cap, binder, pulled):  # pragma: no cover - compiled
    for i in range(own.size):
        o = own[i]
        j = o + 1
        while j < run_end[o]:
            ahead = point_pos[j] - s[i]
            if ahead > reach:
                break
            lead = point_vehicle[j]
            if ahead > tie or rank[lead] > rank[i]:
                _bind(i, j, lead, point_pos, s, u, gap, b, dt, cap, binder, pulled)
            j += 1
        j = o - 1
        while j >= run_start[o]:
            ahead = point_pos[j] - s[i]
            if ahead < -tie or ahead > tie:
                break
            lead = point_vehicle[j]
            if rank[lead] > rank[i]:
                _bind(i, j, lead, point_pos, s, u, gap, b, dt, cap, binder, pulled)
            j -= 1


def scan(
    own: np.ndarray, run_start: np.ndarray, run_end: np.ndarray, point_pos: np.ndarray,
    point_vehicle: np.ndarray, s: np.ndarray, u: np.ndarray, rank: np.ndarray, reach: float,
    tie: float, gap: float, b: float, dt: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(cap, binder, pulled) of every vehicle, or None without numba (arguments as in
    :func:`mivecc_env.sim.rule_shield.scan_reference`)."""
    if not HAVE_NUMBA:
        return None
    n = own.size
    cap = np.full(n, np.inf)
    binder = np.full(n, -1, dtype=np.int64)
    pulled = np.zeros(n, dtype=np.bool_)
    _scan(own, run_start, run_end, point_pos, point_vehicle, s, u, rank, float(reach),
          float(tie), float(gap), float(b), float(dt), cap, binder, pulled)
    return cap, binder, pulled
