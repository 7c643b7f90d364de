"""Compiled (numba) build of the virtual-lane view: the same result as the numpy reference.

:func:`build_view_fast` returns exactly (bit for bit, element for element) what
:func:`mivecc_env.sim.virtual_lane.build_view_reference` returns, in two compiled passes and one
sort:

1. one pass over the vehicle slots gathers the active vehicles and their projections (the
   reference's point order: own points in slot order, then projections by vehicle and conflict
   column) and packs each point's sort key ``(group, position quantised to 0.1 mm, point
   index)`` into one unique non-negative ``int64``;
2. ``np.sort`` of those keys (unique keys: any sort gives the order of the reference's stable
   radix sort, including its ties, which keep the input order);
3. one pass over the sorted points gives the runs of equal group, every vehicle's front and back
   point and distances, and the own-lane leader and follower.

Only integer work, comparisons and the reference's own float additions and subtractions (same
operands, same order, no fast-math) happen in the kernels, so results are identical. When numba
is not installed, or when a batch is too large for the packed key (the reference then falls
back to a float argsort), :func:`build_view_fast` returns None and the caller uses the reference.
Set ``MIVECC_NO_NUMBA=1`` to force the reference path.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mivecc_env.sim._numba import HAVE_NUMBA, njit

if TYPE_CHECKING:
    from mivecc_env.sim.network import GridNetwork
    from mivecc_env.sim.virtual_lane import VirtualLaneView


@njit
def _points(active, lane, s, lane_cp_s, lane_cp_other_lane, lane_cp_other_s, window_m,
            clear_m, seg, off, n_on, candidate, n_lanes, q_scale, qbits, ibits):  # pragma: no cover
    """Pass 1: vehicles, points and packed sort keys (see the module docstring)."""
    bsz, cap = active.shape
    n = 0
    for b in range(bsz):
        for k in range(cap):
            if active[b, k]:
                n += 1
    n_col = 2 if candidate else lane_cp_s.shape[1]
    vehicle = np.empty(n, np.int64)
    env = np.empty(n, np.int64)
    v_lane = np.empty(n, np.int64)
    v_s = np.empty(n, np.float64)
    i = 0
    for b in range(bsz):
        for k in range(cap):
            if active[b, k]:
                vehicle[i] = b * cap + k
                env[i] = b
                v_lane[i] = lane[b, k]
                v_s[i] = s[b, k]
                i += 1
    max_p = n * (1 + n_col)
    group = np.empty(max_p, np.int64)
    pos = np.empty(max_p, np.float64)
    src = np.empty(max_p, np.int64)
    for i in range(n):
        group[i] = env[i] * n_lanes + v_lane[i]
        pos[i] = v_s[i]
        src[i] = i
    p = n
    for i in range(n):
        ln = v_lane[i]
        first = 0
        if candidate:
            kc = np.int64(np.ceil((v_s[i] - clear_m - off) / seg)) - 1
            kc = min(max(kc, 0), n_on - 1)
            first = 2 * kc
        for j in range(n_col):
            c = first + j
            delta = v_s[i] - lane_cp_s[ln, c]
            if delta >= -window_m and delta <= clear_m:
                group[p] = env[i] * n_lanes + lane_cp_other_lane[ln, c]
                pos[p] = lane_cp_other_s[ln, c] + delta
                src[p] = i
                p += 1
    size = p
    keys = np.empty(size, np.int64)
    qmax = (np.int64(1) << qbits) - 1
    shift_g = qbits + ibits
    ok = True
    for j in range(size):
        q = np.int64((pos[j] + window_m) * q_scale)
        if q > qmax or q < 0:
            ok = False
        keys[j] = (group[j] << shift_g) | (q << ibits) | j
    return vehicle, env, v_lane, v_s, pos[:size], src[:size], keys, ok


@njit
def _neighbours(keys, pos, src, n, v_s, imask, shift_g):  # pragma: no cover
    """Pass 2: sorted point arrays, runs, front/back points and own-lane neighbours."""
    size = keys.size
    g_s = np.empty(size, np.int64)
    p_s = np.empty(size, np.float64)
    s_s = np.empty(size, np.int64)
    own = np.empty(size, np.bool_)
    own_point = np.empty(n, np.int64)
    run_start = np.empty(size, np.int64)
    run_end = np.empty(size, np.int64)
    front = np.empty(n, np.int64)
    back = np.empty(n, np.int64)
    d_front = np.empty(n, np.float64)
    d_back = np.empty(n, np.float64)
    leader = np.empty(n, np.int64)
    follower = np.empty(n, np.int64)
    start = 0
    prev_own = -1  # last own point of the current run
    for r in range(size):
        j = keys[r] & imask
        g = keys[r] >> shift_g  # the group: the key's top bits
        g_s[r] = g
        p_s[r] = pos[j]
        s_s[r] = src[j]
        if r > 0 and g != g_s[r - 1]:
            for t in range(start, r):
                run_end[t] = r
            start = r
            prev_own = -1
        run_start[r] = start
        if j < n:
            own[r] = True
            own_point[j] = r
            leader[j] = -1
            if prev_own >= 0:
                behind = s_s[prev_own]
                leader[behind] = j
                follower[j] = behind
            else:
                follower[j] = -1
            prev_own = r
        else:
            own[r] = False
    for t in range(start, size):
        run_end[t] = size
    for r in range(size):
        if own[r]:
            i = s_s[r]
            if r + 1 < run_end[r]:
                front[i] = r + 1
                d_front[i] = p_s[r + 1] - v_s[i]
            else:
                front[i] = -1
                d_front[i] = np.inf
            if r - 1 >= run_start[r]:
                back[i] = r - 1
                d_back[i] = v_s[i] - p_s[r - 1]
            else:
                back[i] = -1
                d_back[i] = np.inf
    return (g_s, p_s, s_s, own, run_start, run_end, own_point, front, back, d_front, d_back,
            leader, follower)


def _bits(x: int) -> int:
    return max(1, int(x).bit_length())


def build_view_fast(
    network: GridNetwork, window_m: float, clear_m: float, active: np.ndarray,
    lane: np.ndarray, s: np.ndarray, q_scale: float, candidate: bool,
) -> VirtualLaneView | None:
    """The compiled view, or None where the reference path must run (see the module doc)."""
    from mivecc_env.sim.virtual_lane import VirtualLaneView

    if not HAVE_NUMBA:
        return None
    bsz, cap = active.shape
    n_lanes = network.n_lanes
    n_groups = bsz * n_lanes
    if n_groups > 1 << 16:  # the reference sorts such batches with a float argsort
        return None
    n_col = 2 if candidate else network.lane_cp_s.shape[1]
    reach = float(np.max(network.lane_length)) + clear_m + window_m
    qbits = _bits(int(reach * q_scale * 1.001) + 2)
    ibits = _bits(bsz * cap * (1 + n_col))
    if qbits > 32 or _bits(n_groups - 1) + qbits + ibits > 63:
        return None
    vehicle, env, v_lane, v_s, pos, src, keys, ok = _points(
        active, lane, s, network.lane_cp_s, network.lane_cp_other_lane,
        network.lane_cp_other_s, float(window_m), float(clear_m),
        float(network.segment_length_m), float(network.lane_offset_m),
        int(network.lane_centres_s.shape[1]), bool(candidate), n_lanes, float(q_scale),
        qbits, ibits,
    )
    if not ok:
        return None
    keys.sort()
    imask = (1 << ibits) - 1
    (g_s, p_s, s_s, own, run_start, run_end, own_point, front, back, d_front, d_back,
     leader, follower) = _neighbours(keys, pos, src, vehicle.size, v_s, imask, qbits + ibits)
    return VirtualLaneView(
        vehicle=vehicle, env=env, lane=v_lane, s=v_s, point_group=g_s, point_pos=p_s,
        point_vehicle=s_s, point_own=own, point_run_start=run_start, point_run_end=run_end,
        own_point=own_point, front_point=front, back_point=back, d_front=d_front,
        d_back=d_back, leader=leader, follower=follower,
    )
