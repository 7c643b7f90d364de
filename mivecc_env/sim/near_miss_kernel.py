"""Compiled (numba) kernel of :meth:`mivecc_env.sim.near_miss.NearMissStats.record_step`.

One pass over the vehicles of a step updates the TTC, PET and own-lane / crossing-pair distance
accumulators in place. It uses the numpy reference's own float operations (same operands, same
order, no fast-math) and processes the PET events in the reference's order, so the accumulators
are bit-identical (``tests/sim/test_near_miss.py`` compares both paths). Returns False without
numba (the caller then runs the numpy reference).
"""

from __future__ import annotations

import numpy as np

from mivecc_env.sim._numba import HAVE_NUMBA, njit


@njit
def _record(env, lane, s_old, s_new, v, front, point_vehicle, d_front, leader, gone, t0, dt,
            mark_pos, mark_cp, cp_s, cp_key, lane_side, seg, off, half, n_on, n_cp, local_ok,
            local_step, n_bins, bin_inv, pet_threshold, min_ttc, hist, min_pet, pet_samples,
            pet_under, last_t, last_side, min_dist):  # pragma: no cover - compiled
    n = env.size
    b = min_ttc.size
    # --- time to collision with the nearest point ahead, when closing in
    for i in range(n):
        f = front[i]
        if f >= 0:
            closing = v[i] - v[point_vehicle[f]]
            if closing > 0.0:
                gap = d_front[i] if d_front[i] > 0.0 else 0.0  # level: 0, never < 0
                ttc = gap / closing
                e = env[i]
                if ttc < min_ttc[e]:
                    min_ttc[e] = ttc
                x = ttc * bin_inv
                k = n_bins if not (x < n_bins) else int(x)
                hist[e, k] += 1
    # --- own-lane gaps after the move
    step_min = np.full(b, np.inf)
    for i in range(n):
        lead = leader[i]
        if lead >= 0:
            gap = s_new[lead] - s_new[i]
            if gone[lead]:
                gap = np.inf
            if gap < step_min[env[i]]:
                step_min[env[i]] = gap
    # --- vehicles near a centre: reach / leave marks crossed, crossing pairs
    max_move = -np.inf
    for i in range(n):
        m = s_new[i] - s_old[i]
        if m > max_move:
            max_move = m
    local = local_ok and max_move <= local_step
    radius = off + max(half + max_move, 2.0 * off)
    inv_seg = 1.0 / seg
    n_ev = 0
    cap = 4 * n if local else 4 * n * n_on
    ev_point = np.empty(cap, np.int64)
    ev_key = np.empty(cap, np.float64)
    ev_t = np.empty(cap, np.float64)
    ev_side = np.empty(cap, np.int64)
    ev_leave = np.empty(cap, np.bool_)
    ev_env = np.empty(cap, np.int64)
    sq = np.full(b * n_cp * 2, np.inf)
    reach2 = 2.0 * off
    for i in range(n):
        kc = np.rint(s_new[i] * inv_seg)
        if local:
            if not (abs(s_new[i] - kc * seg) < radius):
                continue
            j0 = min(max(int(kc) - 1, 0), n_on - 1)
            j1 = j0 + 1
        else:
            j0, j1 = 0, n_on
        ln = lane[i]
        e = env[i]
        so, sn = s_old[i], s_new[i]
        side = lane_side[ln]
        for j in range(j0, j1):
            row = ln * n_on + j
            for c in range(4):
                mp = mark_pos[row, c]
                if so < mp and sn >= mp:
                    t_rel = (mp - so) / (sn - so) * dt
                    p = e * n_cp + mark_cp[row, c]
                    ev_point[n_ev] = p
                    ev_key[n_ev] = p * (2.0 * dt) + t_rel
                    ev_t[n_ev] = t_rel + t0[e]
                    ev_side[n_ev] = side
                    ev_leave[n_ev] = (c & 1) == 1
                    ev_env[n_ev] = e
                    n_ev += 1
            for c in range(2):
                d = sn - cp_s[row, c]
                if abs(d) < reach2:
                    q = e * (2 * n_cp) + cp_key[row, c]
                    d2 = d * d
                    if d2 < sq[q]:
                        sq[q] = d2
    # PET: events in time order per point (a stable sort, as the reference)
    order = np.argsort(ev_key[:n_ev], kind="mergesort")
    for o in range(n_ev):
        q = order[o]
        p = ev_point[q]
        if ev_leave[q]:
            last_t[p] = ev_t[q]
            last_side[p] = ev_side[q]
        elif last_side[p] + ev_side[q] == 1:
            pet = ev_t[q] - last_t[p]
            e = ev_env[q]
            if pet < min_pet[e]:
                min_pet[e] = pet
            pet_samples[e] += 1
            if pet < pet_threshold:
                pet_under[e] += 1
    for e in range(b):
        for c in range(n_cp):
            q = (e * n_cp + c) * 2
            pair = np.sqrt(sq[q] + sq[q + 1])
            if pair < step_min[e]:
                step_min[e] = pair
        if step_min[e] < min_dist[e]:
            min_dist[e] = step_min[e]


def record(*args: object) -> bool:
    """Run the kernel (arguments of ``_record``); False when numba is missing."""
    if not HAVE_NUMBA:
        return False
    _record(*args)
    return True
