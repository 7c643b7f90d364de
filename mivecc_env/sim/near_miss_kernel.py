"""Compiled (numba) kernel of :meth:`mivecc_env.sim.near_miss.NearMissStats.record_step`.

A pass over the vehicles of a step lists the closing-in and near-centre vehicles and updates
the own-lane gap accumulators; then the TTC divisions and histogram, the reach / leave events
of the vehicles near an intersection centre and the crossing-pair distances follow, each over
its list; all accumulators are updated in place. It uses the numpy reference's
own float operations (same operands, same order, no fast-math), so the accumulators are
bit-identical (``tests/sim/test_near_miss.py`` and ``test_near_miss_long.py`` compare both
paths, the latter at every step of long busy runs):

* The data-dependent tests (is the vehicle closing in? near a centre?) append its index to a
  list without a branch; the work on the listed vehicles follows in a second loop.

* PET events: the reference processes them in a stable sort by ``point * 2 dt + t_rel``. Events
  of different points never interact (each point has its own last leave; the per-environment
  minimum and counts do not depend on the order), so a point with one event this step is
  processed at once, and only the events of points with several are sorted (stably, by the same
  float key: the same order per point as the reference's sort).
* Crossing pairs: only the (point, side) cells written this step can lower a minimum (an unwritten
  cell is ``inf``, and so is any ``hypot`` with it): each written cell is listed once, the
  points with both cells written are read, and the listed cells cleared.

Scratch buffers (:class:`NearMissScratch`) are owned by the caller and reused across steps;
only a point with several events in one step allocates (the keys of their stable sort).
Returns False without numba (the caller then runs the reference).
"""

from __future__ import annotations

import numpy as np

from mivecc_env.sim._numba import HAVE_NUMBA, njit


class NearMissScratch:
    """Reusable work arrays of the kernel for ``batch_size`` environments of ``n_cp`` points.

    Two flat buffers (one int64, one float64: few arguments keep numba's per-call cost low at
    B = 1) that the kernel slices (layout in ``_record``). Their heads persist between calls:
    the per-point event counts (B * n_cp) are zero and the crossing-pair cells (B * n_cp * 2)
    ``inf``; the rest grows with the number of vehicles (:meth:`ensure`).
    """

    def __init__(self, batch_size: int, n_cp: int) -> None:
        self.n_points = batch_size * n_cp
        self.batch_size = batch_size
        self.ints = np.zeros(0, dtype=np.int64)
        self.floats = np.zeros(0, dtype=np.float64)
        self.ensure(0, 1)

    def ensure(self, n_vehicles: int, n_on: int) -> None:
        """Room for ``n_vehicles`` on lanes of ``n_on`` intersections (heads kept clean)."""
        n, cap, cells = n_vehicles, 4 * n_vehicles * n_on, 2 * n_vehicles * n_on
        need_int = self.n_points + n + 2 * cells + 5 * cap
        if self.ints.size < need_int:
            self.ints = np.zeros(max(need_int, 2 * self.ints.size), dtype=np.int64)
        need_float = 2 * self.n_points + self.batch_size + n + 2 * cap
        if self.floats.size < need_float:
            self.floats = np.full(max(need_float, 2 * self.floats.size), np.inf)


@njit
def _record(env, lane, s_old, s_new, v, front, point_vehicle, d_front, leader, gone, t0, dt,
            mark_pos, mark_cp, cp_s, cp_key, lane_side, geom, n_on, n_cp, local_ok, n_bins,
            min_ttc, hist, min_pet, pet_samples, pet_under, last_t, last_side, min_dist,
            ints, floats):  # pragma: no cover - compiled
    seg, off, half, local_step, bin_inv, pet_threshold = (
        geom[0], geom[1], geom[2], geom[3], geom[4], geom[5])
    n = env.size
    b = min_ttc.size
    # work arrays (see NearMissScratch): ints = count | cand | touched | touched_env | ev_int,
    # floats = sq | step_min | cand_closing | ev_float
    n_pt = b * n_cp
    cap = 4 * n * n_on
    cells = 2 * n * n_on
    count = ints[:n_pt]
    cand = ints[n_pt:n_pt + n]
    touched = ints[n_pt + n:n_pt + n + cells]
    touched_env = ints[n_pt + n + cells:n_pt + n + 2 * cells]
    o0 = n_pt + n + 2 * cells
    ev_int = ints[o0:o0 + 5 * cap].reshape((cap, 5))
    sq = floats[:2 * n_pt]
    step_min = floats[2 * n_pt:2 * n_pt + b]
    cand_closing = floats[2 * n_pt + b:2 * n_pt + b + n]
    o1 = 2 * n_pt + b + n
    ev_float = floats[o1:o1 + 2 * cap].reshape((cap, 2))
    step_min[:] = np.inf
    max_move = -np.inf
    # The data-dependent tests (closing in? near a centre?) append the index to a list without
    # a branch; the work on the listed vehicles follows in a second loop.
    n_close = 0
    for i in range(n):
        f = front[i]
        closing = v[i] - v[point_vehicle[f if f >= 0 else 0]]
        cand[n_close] = i
        cand_closing[n_close] = closing
        n_close += (f >= 0) & (closing > 0.0)
        # --- own-lane gaps after the move
        lead = leader[i]
        if lead >= 0:
            gap = s_new[lead] - s_new[i]
            if gone[lead]:
                gap = np.inf
            e = env[i]
            if gap < step_min[e]:
                step_min[e] = gap
        m = s_new[i] - s_old[i]
        if m > max_move:
            max_move = m
    # --- time to collision with the nearest point ahead, when closing in: the divisions
    # first (a histogram cell chosen by a division just done stalls the loop), then the
    # minimum and the histogram
    for o in range(n_close):
        i = cand[o]
        gap = d_front[i] if d_front[i] > 0.0 else 0.0  # level: 0, never < 0
        cand_closing[o] = gap / cand_closing[o]
    for o in range(n_close):
        ttc = cand_closing[o]
        e = env[cand[o]]
        if ttc < min_ttc[e]:
            min_ttc[e] = ttc
        x = ttc * bin_inv
        k = n_bins if not (x < n_bins) else int(x)
        hist[e, k] += 1
    # --- vehicles near a centre: reach / leave marks crossed, crossing pairs
    local = local_ok and max_move <= local_step
    radius = off + max(half + max_move, 2.0 * off)
    inv_seg = 1.0 / seg
    n_near = 0
    for i in range(n):
        kc = np.rint(s_new[i] * inv_seg)
        cand[n_near] = i
        n_near += (not local) | (abs(s_new[i] - kc * seg) < radius)
    n_ev = 0
    n_sq = 0
    reach2 = 2.0 * off
    for o in range(n_near):
        i = cand[o]
        if local:
            kc = np.rint(s_new[i] * inv_seg)
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
                    ev_int[n_ev, 0] = p
                    ev_int[n_ev, 1] = side
                    ev_int[n_ev, 2] = c & 1  # marks alternate reach, leave
                    ev_int[n_ev, 3] = e
                    ev_float[n_ev, 0] = t_rel
                    ev_float[n_ev, 1] = t_rel + t0[e]
                    count[p] += 1
                    n_ev += 1
            for c in range(2):  # without a branch: whether a cell is new is a coin toss
                d = sn - cp_s[row, c]
                near_cp = abs(d) < reach2
                q = e * (2 * n_cp) + cp_key[row, c] if near_cp else 0
                d2 = d * d
                old = sq[q]
                touched[n_sq] = q  # listed when first written in this step
                touched_env[n_sq] = e
                n_sq += near_cp & (old == np.inf)
                sq[q] = d2 if near_cp and d2 < old else old
    # PET: a point with one event at once; the others in the reference's (stable) order

    def pet_event(o):  # inlined (a call of a compiled function costs more than its work)
        p = ev_int[o, 0]
        if ev_int[o, 2] == 1:
            last_t[p] = ev_float[o, 1]
            last_side[p] = ev_int[o, 1]
        elif last_side[p] + ev_int[o, 1] == 1:
            pet = ev_float[o, 1] - last_t[p]
            e = ev_int[o, 3]
            if pet < min_pet[e]:
                min_pet[e] = pet
            pet_samples[e] += 1
            if pet < pet_threshold:
                pet_under[e] += 1

    n_multi = 0
    for o in range(n_ev):
        if count[ev_int[o, 0]] > 1:
            ev_int[n_multi, 4] = o
            n_multi += 1
        else:
            pet_event(o)
    if n_multi:
        key = np.empty(n_multi, np.float64)
        for k in range(n_multi):
            o = ev_int[k, 4]
            key[k] = ev_int[o, 0] * (2.0 * dt) + ev_float[o, 0]
        order = np.argsort(key, kind="mergesort")
        for k in range(n_multi):
            pet_event(ev_int[order[k], 4])
    for o in range(n_ev):
        count[ev_int[o, 0]] = 0
    # A point's pair distance is finite only when both of its cells were written; each point
    # is read once, from its first (even) cell.
    for o in range(n_sq):
        q = touched[o]
        if (q & 1) == 0 and sq[q + 1] != np.inf:
            pair = np.sqrt(sq[q] + sq[q + 1])
            e = touched_env[o]
            if pair < step_min[e]:
                step_min[e] = pair
    for o in range(n_sq):
        sq[touched[o]] = np.inf
    for e in range(b):
        if step_min[e] < min_dist[e]:
            min_dist[e] = step_min[e]


def record(*args: object) -> bool:
    """Run the kernel (arguments of ``_record``); False when numba is missing."""
    if not HAVE_NUMBA:
        return False
    _record(*args)
    return True
