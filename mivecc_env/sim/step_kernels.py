"""Compiled (numba) kernels of one simulator step, each identical to a numpy reference.

* :func:`safety_inputs` - nearest distance, time to collision and the SV_acc acceleration of
  every vehicle (reference: ``Simulator._safety_inputs_reference``);
* :func:`collision_pairs` - vehicle pairs closer than a vehicle length after a move
  (reference: ``mivecc_env.sim.core.collision_pairs_reference``);
* :func:`blocked_entries` - entry lanes with a vehicle closer than the clearance to the entry.

Only comparisons and the reference's own float operations (same operands, same order, IEEE
arithmetic, no fast-math) are used, so the results are bit-identical; the tests compare each
kernel with its reference. Each function returns None when numba is missing (the caller then
runs the reference).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mivecc_env.sim._numba import HAVE_NUMBA, njit


@njit
def _safety_inputs(v_all, a_all, vehicle, point_vehicle, front, back, d_front, d_back,
                   ego_acc):  # pragma: no cover
    n = vehicle.size
    d_nearest = np.empty(n, np.float64)
    ttc = np.empty(n, np.float64)
    acc = np.empty(n, np.float64)
    for i in range(n):
        v = v_all[vehicle[i]]
        df, db = d_front[i], d_back[i]
        d = df if df < db else db
        if df <= db:
            vf = v_all[vehicle[point_vehicle[front[i]]]] if front[i] >= 0 else 0.0
            closing = v - vf
        else:
            vb = v_all[vehicle[point_vehicle[back[i]]]] if back[i] >= 0 else 0.0
            closing = vb - v
        d_nearest[i] = d
        ttc[i] = d / closing if (closing > 0 and d != np.inf) else np.inf
        if ego_acc:
            acc[i] = a_all[vehicle[i]]
        else:
            acc[i] = a_all[vehicle[point_vehicle[front[i]]]] if front[i] >= 0 else 0.0
    return d_nearest, ttc, acc


def safety_inputs(
    v_all: NDArray[np.float64], a_all: NDArray[np.float64], vehicle: NDArray[np.int64],
    point_vehicle: NDArray[np.int64], front: NDArray[np.int64], back: NDArray[np.int64],
    d_front: NDArray[np.float64], d_back: NDArray[np.float64], ego_acc: bool,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
    """(d_nearest [m], ttc [s], acc [m/s^2]) per view vehicle; ``v_all``/``a_all`` flat."""
    if not HAVE_NUMBA:
        return None
    return _safety_inputs(v_all, a_all, vehicle, point_vehicle, front, back, d_front, d_back,
                          bool(ego_acc))


@njit
def _near_conflict_point(x, seg, reach):  # pragma: no cover
    return np.abs(x - np.rint(x / seg) * seg) < reach


@njit
def _collision_pairs(leader, s_new, exited, lane, env, lane_cp, lane_cp_s, n_cp, seg, off,
                     length):  # pragma: no cover
    # Arrays are sized by upper bounds (growing them inside a loop defeats numba's optimiser).
    n = s_new.size
    n_col = lane_cp_s.shape[1]
    reach = off + length
    # vehicles within a vehicle length of a conflict point, in (vehicle, column) order
    m = 0
    for i in range(n):
        if not exited[i] and _near_conflict_point(s_new[i], seg, reach):
            for c in range(n_col):
                if np.abs(s_new[i] - lane_cp_s[lane[i], c]) < length:
                    m += 1
    vi = np.empty(m, np.int64)
    key = np.empty(m, np.int64)
    dd = np.empty(m, np.float64)
    j = 0
    for i in range(n):
        if not exited[i] and _near_conflict_point(s_new[i], seg, reach):
            ln = lane[i]
            for c in range(n_col):
                delta = s_new[i] - lane_cp_s[ln, c]
                if np.abs(delta) < length:
                    vi[j] = i
                    key[j] = env[i] * n_cp + lane_cp[ln, c]
                    dd[j] = delta
                    j += 1
    pa = np.empty(n + 7 * m, np.int64)
    pb = np.empty(n + 7 * m, np.int64)
    k = 0
    for i in range(n):
        ld = leader[i]
        if ld >= 0 and not exited[i] and not exited[ld] and s_new[ld] - s_new[i] < length:
            pa[k] = i
            pb[k] = ld
            k += 1
    if m > 1:
        order = np.argsort(key, kind="mergesort")
        vs, ks, ds = vi[order], key[order], dd[order]
        for shift in range(1, 8):  # as the reference: at most a few vehicles share a point
            if shift >= m:
                break
            for a in range(m - shift):
                b = a + shift
                if (ks[a] == ks[b] and lane[vs[a]] != lane[vs[b]]
                        and ds[a] ** 2 + ds[b] ** 2 < length ** 2):
                    pa[k] = vs[a]
                    pb[k] = vs[b]
                    k += 1
    return pa[:k], pb[:k]


def collision_pairs(
    leader: NDArray[np.int64], s_new: NDArray[np.float64], exited: NDArray[np.bool_],
    lane: NDArray[np.int64], env: NDArray[np.int64], lane_cp: NDArray[np.int64],
    lane_cp_s: NDArray[np.float64], n_cp: int, seg: float, off: float, length: float,
) -> NDArray[np.int64] | None:
    """(k, 2) sorted unique view-index pairs closer than ``length`` [m] (see the reference)."""
    if not HAVE_NUMBA:
        return None
    a, b = _collision_pairs(leader, s_new, exited, lane, env, lane_cp, lane_cp_s, int(n_cp),
                            float(seg), float(off), float(length))
    if a.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return np.unique(np.sort(np.stack([a, b], axis=1), axis=1), axis=0)


@njit
def _blocked_entries(active, lane, s, clearance, n_lanes):  # pragma: no cover
    bsz, cap = active.shape
    blocked = np.zeros((bsz, n_lanes), np.bool_)
    for b in range(bsz):
        for k in range(cap):
            if active[b, k] and s[b, k] < clearance:
                blocked[b, lane[b, k]] = True
    return blocked


def blocked_entries(
    active: NDArray[np.bool_], lane: NDArray[np.int64], s: NDArray[np.float64],
    clearance_m: float, n_lanes: int,
) -> NDArray[np.bool_] | None:
    """(B, n_lanes) True where a vehicle of that entry lane is closer than ``clearance_m``."""
    if not HAVE_NUMBA:
        return None
    return _blocked_entries(active, lane, s, float(clearance_m), int(n_lanes))
