"""Compiled (numba) kernels of one simulator step, each identical to a numpy reference.

* :func:`safety_inputs` - nearest distance, time to collision and the SV_acc acceleration of
  every vehicle (reference: ``Simulator._safety_inputs_reference``);
* :func:`collision_pairs` - vehicle pairs closer than a vehicle length after a move
  (reference: ``mivecc_env.sim.core.collision_pairs_reference``);
* :func:`safety_fast` - the inputs and the safety value in two passes around numpy's own logs
  (reference: ``safety_value`` of the reference inputs);
* :func:`move` - end rule, fusion and bounded motion of the plain unsignalized model, state
  written in place (reference: ``Simulator._move``);
* :func:`entry_plan` / :func:`place_entries` - queued vehicles entering free slots, the blocked
  entries found from the step's view (reference: the numpy body of
  ``Simulator._enter_vehicles``); :func:`advance_arrivals` - the counting loop
  of ``ArrivalProcess.advance``;
* :func:`record_exits` / :func:`record_passing` - trip and passing-time accumulators
  (references: ``Simulator._record_exits``, ``PassingTimes.record``);
* :func:`box_blocked` - the signals' keep-clear check, each vehicle's walk along its leaders
  (reference: ``mivecc_env.sim.signals.box_blocked_reference``).

Only comparisons and the reference's own float operations (same operands, same order, IEEE
arithmetic, no fast-math) are used, so the results are bit-identical; the tests compare each
kernel with its reference (``tests/sim/test_kernels.py``). Each function returns None (False)
when numba is missing (the caller then runs the reference).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim._numba import HAVE_NUMBA, njit
from mivecc_env.sim.safety import MIN_DISTANCE_M, MIN_TTC_S, SV_T_SAFE


@njit
def _gather_neighbours(v_all, a_all, vehicle, point_vehicle, front, back, d_front, d_back,
                       ego_acc, closing, acc):  # pragma: no cover
    """Write each view vehicle's closing speed on its nearer neighbour [m/s] into
    ``closing`` and its SV_acc acceleration [m/s^2] into ``acc`` (one formula for
    :func:`_safety_inputs` and :func:`_safety_prep`).

    Both neighbours are read and the nearer one selected without a branch: which one is
    nearer is a coin toss per vehicle, a branch on it mispredicts half the time."""
    for i in range(vehicle.size):
        k = vehicle[i]
        v = v_all[k]
        f, bk = front[i], back[i]
        kf = vehicle[point_vehicle[f if f >= 0 else 0]]
        kb = vehicle[point_vehicle[bk if bk >= 0 else 0]]
        vf = v_all[kf] if f >= 0 else 0.0
        vb = v_all[kb] if bk >= 0 else 0.0
        closing[i] = (v - vf) if d_front[i] <= d_back[i] else (vb - v)
        if ego_acc:
            acc[i] = a_all[k]
        else:
            acc[i] = a_all[kf] if f >= 0 else 0.0


@njit
def _ttc_of(d, closing):  # pragma: no cover
    """Time to collision [s] at distance ``d`` [m] and closing speed ``closing`` [m/s]."""
    return d / closing if (closing > 0) & (d != np.inf) else np.inf


@njit
def _safety_inputs(v_all, a_all, vehicle, point_vehicle, front, back, d_front, d_back,
                   ego_acc):  # pragma: no cover
    n = vehicle.size
    d_nearest = np.empty(n, np.float64)
    ttc = np.empty(n, np.float64)
    acc = np.empty(n, np.float64)
    _gather_neighbours(v_all, a_all, vehicle, point_vehicle, front, back, d_front, d_back,
                       ego_acc, ttc, acc)
    for i in range(n):
        df, db = d_front[i], d_back[i]
        d = df if df < db else db
        d_nearest[i] = d
        ttc[i] = _ttc_of(d, ttc[i])
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
def _safety_prep(v_all, a_all, vehicle, point_vehicle, front, back, d_front, d_back, ego_acc,
                 min_d, alpha_d, thr, alpha_acc):  # pragma: no cover
    """:func:`_safety_inputs` plus the arguments of the safety value's two logs.

    Two passes: the gathers (:func:`_gather_neighbours`), then the arithmetic on contiguous
    arrays (vectorised by the compiler). ``ttc`` holds the closing speed between the two."""
    n = vehicle.size
    out = np.empty(4 * n, np.float64)  # ttc, acc, logs: one array returned (one boxing call)
    ttc = out[:n]
    acc = out[n:2 * n]
    logs = out[2 * n:]  # d / alpha_d, then min(d_front / thr, alpha_acc)
    _gather_neighbours(v_all, a_all, vehicle, point_vehicle, front, back, d_front, d_back,
                       ego_acc, ttc, acc)
    n_sensitive = 0
    for i in range(n):
        df, db = d_front[i], d_back[i]
        d = df if df < db else db
        t = _ttc_of(d, ttc[i])
        ttc[i] = t
        n_sensitive += (t > 0.0) & (t < 1.0)
        logs[i] = (d if d > min_d else min_d) / alpha_d
        r = (df if df > min_d else min_d) / thr
        logs[n + i] = r if r < alpha_acc else alpha_acc
    return out, n_sensitive


@njit
def _sensitive(ttc, n_sensitive):  # pragma: no cover
    """Indices (ascending) of the ``n_sensitive`` TTCs in (0, 1) s (listed without a branch)."""
    idx = np.empty(n_sensitive + 1, np.int64)
    k = 0
    for i in range(ttc.size):
        t = ttc[i]
        idx[k] = i
        k += (t > 0.0) & (t < 1.0)
    return idx[:n_sensitive]


@njit
def _safety_combine(logs, sensitive, sv_t_sensitive, d_front, acc, beta_d, beta_acc,
                    lambda_acc, sv_t_safe, sv_min, sv_max):  # pragma: no cover
    """The safety value from the logs (same operations and order as ``safety_value``): every
    vehicle with SV_t = ``sv_t_safe`` (a loop the compiler vectorises), then the few
    ``sensitive`` ones again with their own SV_t."""
    n = d_front.size
    sv = np.empty(n, np.float64)
    for i in range(n):
        sv[i] = _sv_of(logs[i], logs[n + i], sv_t_safe, d_front[i], acc[i], beta_d, beta_acc,
                       lambda_acc, sv_min, sv_max)
    for k in range(sensitive.size):
        i = sensitive[k]
        sv[i] = _sv_of(logs[i], logs[n + i], sv_t_sensitive[k], d_front[i], acc[i], beta_d,
                       beta_acc, lambda_acc, sv_min, sv_max)
    return sv


@njit
def _sv_of(log_d, log_acc, sv_t, d_front, acc, beta_d, beta_acc, lambda_acc, sv_min,
           sv_max):  # pragma: no cover
    x = beta_d * log_d + sv_t
    x = x + (lambda_acc * acc * (beta_acc * log_acc) if d_front != np.inf else 0.0)
    x = x if x > sv_min else sv_min
    return x if x < sv_max else sv_max


def safety_fast(
    v_all: NDArray[np.float64], a_all: NDArray[np.float64], vehicle: NDArray[np.int64],
    point_vehicle: NDArray[np.int64], front: NDArray[np.int64], back: NDArray[np.int64],
    d_front: NDArray[np.float64], d_back: NDArray[np.float64], config: MiVeCCConfig,
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """(SV, ttc [s]) per view vehicle: :func:`safety_inputs` then ``safety_value``, fused.

    Bit-identical to ``safety_value(*reference inputs)``: the logs and the tanh/power (only
    where 0 < TTC < 1 s) are numpy's own calls on the same values; the rest is the reference's
    IEEE arithmetic in the same order. None when numba is missing or for the released code's
    SV variants (epsilons, a no-front distance), which run the reference.
    """
    c = config
    if (not HAVE_NUMBA or c.sv_d_epsilon > 0.0 or c.sv_acc_epsilon > 0.0
            or c.sv_no_front_distance_m is not None):
        return None
    prep, n_sensitive = _safety_prep(
        v_all, a_all, vehicle, point_vehicle, front, back, d_front, d_back,
        c.sv_acc_source == "ego", MIN_DISTANCE_M, float(c.sv_alpha_d),
        float(c.sv_d_threshold_m), float(c.sv_alpha_acc),
    )
    n = vehicle.size
    ttc, acc, logs = prep[:n], prep[n:2 * n], prep[2 * n:]
    np.log(logs, out=logs)
    if n_sensitive:
        sensitive = _sensitive(ttc, n_sensitive)
        t = np.maximum(ttc[sensitive], MIN_TTC_S)
        sv_t = -((c.sv_alpha_t / np.tanh(t)) ** c.sv_beta_t)
    else:
        sensitive, sv_t = _NO_INDEX, _NO_VALUE
    sv = _safety_combine(logs, sensitive, sv_t, d_front, acc, float(c.sv_beta_d),
                         float(c.sv_beta_acc), float(c.sv_lambda_acc), SV_T_SAFE,
                         float(c.sv_min), float(c.sv_max))
    return sv, ttc


_NO_INDEX = np.zeros(0, dtype=np.int64)
_NO_VALUE = np.zeros(0, dtype=np.float64)


@njit
def _collision_pairs(leader, s_new, exited, lane, env, lane_cp, lane_cp_s, n_cp, seg, off,
                     length):  # pragma: no cover
    """(k, 2) sorted unique pairs: the reference's candidates, then its ``np.unique``."""
    n = s_new.size
    n_col = lane_cp_s.shape[1]
    reach = off + length
    # Own-lane pairs; and the vehicles near an intersection centre, listed without a branch.
    pa = np.empty(n, np.int64)
    pb = np.empty(n, np.int64)
    near = np.empty(n, np.int64)
    k = 0
    n_near = 0
    # x * (1 / seg) rounds to another integer than the reference's x / seg only next to a half
    # segment, far outside ``reach``: the same vehicles pass
    inv_seg = 1.0 / seg
    for i in range(n):
        x = s_new[i]
        near[n_near] = i
        n_near += (not exited[i]) & (np.abs(x - np.rint(x * inv_seg) * seg) < reach)
        ld = leader[i]
        if ld >= 0 and not exited[i] and not exited[ld] and s_new[ld] - x < length:
            pa[k] = i
            pb[k] = ld
            k += 1
    # near vehicles within a vehicle length of a conflict point, in (vehicle, column) order
    m = 0
    for o in range(n_near):
        i = near[o]
        for c in range(n_col):
            if np.abs(s_new[i] - lane_cp_s[lane[i], c]) < length:
                m += 1
    vi = np.empty(m, np.int64)
    key = np.empty(m, np.int64)
    dd = np.empty(m, np.float64)
    j = 0
    n_key = 0
    for o in range(n_near):
        i = near[o]
        ln = lane[i]
        for c in range(n_col):
            delta = s_new[i] - lane_cp_s[ln, c]
            if np.abs(delta) < length:
                vi[j] = i
                key[j] = env[i] * n_cp + lane_cp[ln, c]
                n_key = max(n_key, key[j] + 1)
                dd[j] = delta
                j += 1
    # The reference pairs each candidate with the next 7 of a stable sort by point: the next 7
    # of its point's list in (vehicle, column) order, linked here without a sort.
    head = np.full(n_key, -1, np.int64)
    nxt = np.empty(m, np.int64)
    for a in range(m - 1, -1, -1):
        nxt[a] = head[key[a]]
        head[key[a]] = a
    ca = np.empty(7 * m, np.int64)
    cb = np.empty(7 * m, np.int64)
    n_cross = 0
    for a in range(m):
        b = nxt[a]
        shift = 1
        while b >= 0 and shift < 8:
            if lane[vi[a]] != lane[vi[b]] and dd[a] ** 2 + dd[b] ** 2 < length ** 2:
                ca[n_cross] = vi[a]
                cb[n_cross] = vi[b]
                n_cross += 1
            b = nxt[b]
            shift += 1
    # np.unique(np.sort(pairs, axis=1), axis=0): rows (lo, hi) in lexicographic order, once
    total = k + n_cross
    if total == 0:
        return np.zeros((0, 2), np.int64)
    code = np.empty(total, np.int64)
    for t in range(total):
        x, y = (pa[t], pb[t]) if t < k else (ca[t - k], cb[t - k])
        code[t] = min(x, y) * n + max(x, y)
    code.sort()
    n_out = 1
    for t in range(1, total):
        n_out += code[t] != code[t - 1]
    out = np.empty((n_out, 2), np.int64)
    r = 0
    for t in range(total):
        if t == 0 or code[t] != code[t - 1]:
            out[r, 0] = code[t] // n
            out[r, 1] = code[t] % n
            r += 1
    return out


def collision_pairs(
    leader: NDArray[np.int64], s_new: NDArray[np.float64], exited: NDArray[np.bool_],
    lane: NDArray[np.int64], env: NDArray[np.int64], lane_cp: NDArray[np.int64],
    lane_cp_s: NDArray[np.float64], n_cp: int, seg: float, off: float, length: float,
) -> NDArray[np.int64] | None:
    """(k, 2) sorted unique view-index pairs closer than ``length`` [m] (see the reference).

    The candidates are the reference's (own-lane neighbours; crossing pairs within 7 places of
    one another in a stable sort by conflict point, found along a linked list per point); the
    unique sorted rows are made in the kernel (an int64 code ``lo * n + hi`` per pair, sorted,
    repeats dropped).
    """
    if not HAVE_NUMBA:
        return None
    return _collision_pairs(leader, s_new, exited, lane, env, lane_cp, lane_cp_s, int(n_cp),
                            float(seg), float(off), float(length))


@njit
def _entry_plan(active, vehicle, env, lane, s_new, queued, clearance):  # pragma: no cover
    """(go (B, n_lanes), rows: vehicles entering per env, free slots per env, nearest
    (B, n_lanes): the lowest position of a lane's vehicles, inf without one)."""
    bsz, n_lanes = queued.shape
    cap = active.size // bsz
    go = np.zeros((bsz, n_lanes), np.bool_)
    nearest = np.full((bsz, n_lanes), np.inf)
    counts = np.zeros((2, bsz), np.int64)
    n_new = counts[0]
    n_free = counts[1]
    for i in range(s_new.size):
        if active[vehicle[i]] and s_new[i] < nearest[env[i], lane[i]]:
            nearest[env[i], lane[i]] = s_new[i]
    for b in range(bsz):
        for ln in range(n_lanes):
            if queued[b, ln] > 0 and not nearest[b, ln] < clearance:
                go[b, ln] = True
                n_new[b] += 1
        # free slots, counted from the end (where they are) until there are enough
        free = 0
        k = (b + 1) * cap - 1
        while free < n_new[b] and k >= b * cap:
            free += not active[k]
            k -= 1
        n_free[b] = free
    return go, counts, nearest


@njit
def _place_entries(go, times, entered, now, active, lane, s, v, a, t_arrive, t_enter, vid,
                   next_vid, v_lane, a_init):  # pragma: no cover
    """Put the head vehicle of every ``go`` lane into its environment's next free slot."""
    bsz = active.shape[0]
    n_lanes = go.shape[1]
    ring = times.shape[2]
    for b in range(bsz):
        k = 0
        ordinal = 0
        for ln in range(n_lanes):
            if not go[b, ln]:
                continue
            while active[b, k]:
                k += 1
            active[b, k] = True
            lane[b, k] = ln
            s[b, k] = 0.0
            v[b, k] = v_lane[b, ln]
            a[b, k] = a_init
            t_arrive[b, k] = times[b, ln, entered[b, ln] % ring]  # the queue's head
            entered[b, ln] += 1
            t_enter[b, k] = now[b]
            vid[b, k] = next_vid[b] + ordinal
            ordinal += 1
        next_vid[b] += ordinal


def entry_plan(
    active: NDArray[np.bool_], vehicle: NDArray[np.int64], env: NDArray[np.int64],
    lane: NDArray[np.int64], s_new: NDArray[np.float64], queued: NDArray[np.int64],
    clearance_m: float,
) -> tuple[NDArray[np.bool_], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]] | None:
    """(go, n_new, n_free, nearest): lanes whose queue head enters (queued and no vehicle of
    the lane closer than ``clearance_m`` to its entry), entries per environment, its free slots
    counted up to n_new (``n_free < n_new``: not enough room, ``n_free`` is then exact), and
    the position of each lane's nearest vehicle to its entry [m] (inf: none).

    The vehicles are read from the view of the step (``vehicle``, ``env``, ``lane``; ``s_new``
    their positions after the move): every active vehicle is in it (a vehicle outside the
    view would not move), those that left or collided are inactive in ``active`` (flat
    (B * capacity,), C order). None when numba is missing."""
    if not HAVE_NUMBA:
        return None
    go, counts, nearest = _entry_plan(active, vehicle, env, lane, s_new, queued,
                                      float(clearance_m))
    n_new, n_free = counts
    return go, n_new, n_free, nearest


def place_entries(
    go: NDArray[np.bool_], ring: tuple[NDArray[np.float64], NDArray[np.int64]],
    now: NDArray[np.float64], state: tuple[NDArray, ...], next_vid: NDArray[np.int64],
    v_lane: NDArray[np.float64], a_init: float,
) -> None:
    """Fill the slots of the entering vehicles in place (the reference's slot order: the
    environment's free slots ascending, lanes ascending) and take them off their queues.
    ``ring``: the arrival process's (times, entered) arrays (the head of a queue is
    ``times[b, lane, entered % ring size]``; ``entered`` is advanced); ``state``: the
    simulator's (active, lane, s, v, a, t_arrive, t_enter, vid) arrays; ``v_lane``: the entry
    speed of each lane (B, n_lanes) [m/s]; ``next_vid`` is advanced."""
    _place_entries(go, *ring, now, *state, next_vid, v_lane, float(a_init))


@njit
def _advance_arrivals(times, generated, arrived, next_time, now, need):  # pragma: no cover
    """Count every buffered arrival with time <= now into ``arrived``; stop a lane where its
    buffer runs low (``need`` True: draw more, then call again). Returns the lanes in need.
    ``next_time``: each lane's ``times`` entry number ``arrived`` (kept up to date here), so
    that a lane without an arrival does not touch its buffer."""
    bsz, n_lanes, cap = times.shape
    n_need = 0
    for b in range(bsz):
        t = now[b]
        for ln in range(n_lanes):
            need[b, ln] = False
            head = next_time[b, ln]
            if not head <= t:
                continue
            arr = arrived[b, ln]
            gen = generated[b, ln]
            while gen - arr >= 2 and head <= t:
                arr += 1
                head = times[b, ln, arr % cap]  # arr < gen: drawn
                if gen - arr < 2:
                    need[b, ln] = True
                    n_need += 1
            arrived[b, ln] = arr
            next_time[b, ln] = head
    return n_need


def advance_arrivals(
    times: NDArray[np.float64], generated: NDArray[np.int64], arrived: NDArray[np.int64],
    next_time: NDArray[np.float64], now: NDArray[np.float64], need: NDArray[np.bool_],
) -> int | None:
    """``ArrivalProcess.advance``'s counting loop (``arrived`` and ``next_time``, the time of
    each lane's next arrival, updated in place); the number of lanes whose buffer must be
    refilled before calling again (``need`` marks them)."""
    if not HAVE_NUMBA:
        return None
    return int(_advance_arrivals(times, generated, arrived, next_time, now, need))


@njit
def _move(vehicle, env, lane, sv, d_front, d_back, edge, cloud, raw, s_all, v_all, a_all,
          lane_length, speed_sum, steps_sum, eta, sensible, entry_accel, gate, use_gate, omega,
          a_max, v_lo, v_hi, dt, rec, t0, t1, mark_s, t_arrive, t_enter, active, passing,
          trips, exited, n_out):  # pragma: no cover
    """Rule, fusion and motion of every view vehicle (the reference's operations in order);
    with ``rec`` also the passing times (``_record_passing``) and the exits
    (``_record_exits``) of the vehicles that cross their mark / leave, in view order.

    Returns (rows s before, v before, s after; exited): two arrays, not four (each array a
    kernel returns costs a boxing call)."""
    n = vehicle.size
    moved = np.empty((3, n), np.float64)
    s_old = moved[0]
    v_old = moved[1]
    s_new = moved[2]
    out = np.empty(n, np.bool_)
    bsz = speed_sum.size
    speed = np.zeros(bsz, np.float64)
    count = np.zeros(bsz, np.int64)
    n_pass = np.zeros(bsz, np.int64)
    part = np.zeros((6, bsz), np.float64)  # passing time, length; the four trip sums
    has_edge = edge.size > 0
    has_cloud = cloud.size > 0
    has_raw = raw.size > 0
    pass_time = part[0]
    pass_length = part[1]
    for i in range(n):
        k = vehicle[i]
        s = s_all[k]
        v = v_all[k]
        ratio = sv[i] / eta
        a = ratio if (d_front[i] <= d_back[i]) == sensible else np.abs(ratio)
        if entry_accel != 0.0 and s == 0.0:
            a = entry_accel
        if has_edge:
            e = edge[k]
            valid = not np.isnan(e)
            use = valid and (not use_gate or sv[i] > gate)
            ev = e if use else 0.0
            if use and ev * a > 0:
                a = ev if ev >= a else a
            if has_raw and raw[env[i]] and valid:
                a = e
        if has_cloud:
            cl = cloud[k]
            if not np.isnan(cl):
                a = (1.0 - omega) * a + omega * cl
        a = a if a > -a_max else -a_max
        a = a if a < a_max else a_max
        lo = (v_lo - v) / dt
        hi = (v_hi - v) / dt
        a = a if a > lo else lo
        a = a if a < hi else hi
        sn = s + v * dt + 0.5 * a * dt * dt
        vn = v + a * dt
        vn = vn if vn > v_lo else v_lo
        vn = vn if vn < v_hi else v_hi
        s_old[i] = s
        v_old[i] = v
        s_new[i] = sn
        s_all[k] = sn
        v_all[k] = vn
        a_all[k] = a
        b = env[i]
        speed[b] += vn
        count[b] += 1
        ln = lane[i]
        length = lane_length[ln]
        out[i] = sn >= length
        if rec:
            _add_passing(n_pass, pass_time, pass_length, b, mark_s[ln], s, sn, t0[b], dt,
                         t_enter[k])
            if sn >= length:
                _add_exit(part[2:], b, length, _exit_time(length, s, sn, t0[b], t1[b]),
                          t_arrive[k], t_enter[k])
                n_out[b] += 1
                active[k] = False
    for b in range(bsz):
        speed_sum[b] += speed[b]
        steps_sum[b] += count[b]
    if rec:
        for b in range(bsz):
            passing[0][b] += n_pass[b]
        for b in range(bsz):
            passing[1][b] += part[0, b]
            passing[2][b] += part[1, b]
            for r in range(4):
                trips[r][b] += part[2 + r, b]
            exited[b] += n_out[b]
    return moved, out


@njit
def _cross_frac(mark, s_old, s_new):  # pragma: no cover
    """Fraction of the step [0, 1] at which a vehicle moving s_old -> s_new reaches ``mark``."""
    step = s_new - s_old
    frac = (mark - s_old) / (step if step >= 1e-12 else 1e-12)
    frac = frac if frac > 0.0 else 0.0
    return frac if frac < 1.0 else 1.0


@njit
def _add_passing(count, time, length, e, mark, s_old, s_new, t0, dt, t_enter):  # pragma: no cover
    """Add a vehicle moving s_old -> s_new in the step from ``t0`` [s] that reaches its
    ``mark`` [m] to environment ``e``'s passing sums: one passing, its time since entry [s],
    the mark's distance [m]."""
    if s_old < mark and s_new >= mark:
        count[e] += 1
        time[e] += t0 + _cross_frac(mark, s_old, s_new) * dt - t_enter
        length[e] += mark


@njit
def _exit_time(length, s_old, s_new, t0, t1):  # pragma: no cover
    """Time [s] at which a vehicle moving s_old -> s_new within (t0, t1) leaves its lane."""
    return t0 + _cross_frac(length, s_old, s_new) * (t1 - t0)


@njit
def _add_exit(part, e, length, t_exit, t_arr, t_ent):  # pragma: no cover
    """Add one exited vehicle to the (4, B) trip sums of environment ``e``."""
    trip = t_exit - t_arr
    part[0, e] += length / trip
    part[1, e] += length / (t_exit - t_ent)
    part[2, e] += trip
    part[3, e] += t_ent - t_arr


_NO_FLOAT = np.zeros(0, dtype=np.float64)
_NO_BOOL = np.zeros(0, dtype=np.bool_)


def move(
    vehicle: NDArray[np.int64], env: NDArray[np.int64], lane: NDArray[np.int64],
    sv: NDArray[np.float64], d_front: NDArray[np.float64], d_back: NDArray[np.float64],
    edge: NDArray[np.float64] | None, cloud: NDArray[np.float64] | None,
    raw: NDArray[np.bool_] | None, state: tuple[NDArray[np.float64], ...],
    lane_length: NDArray[np.float64], sums: tuple[NDArray[np.float64], NDArray[np.int64]],
    config: MiVeCCConfig, record: tuple | None = None,
) -> tuple[NDArray, ...] | None:
    """One step of the plain unsignalized model for every view vehicle, compiled.

    ``end_accel`` (+ ``entry_action``), ``fuse`` (edge, raw edge, cloud, clip) and
    ``bounded_motion`` per vehicle with the reference's IEEE operations in the same order;
    writes the new position, velocity and applied acceleration into ``state`` = the flat
    (s, v, a) arrays and adds the per-environment speed sum and vehicle count into ``sums``.
    ``edge`` / ``cloud``: flat (B * capacity,) actions (NaN: none) or None; ``raw``: (B,) or
    None. The caller checks that no rule outside these applies.

    ``record``: also do :func:`record_passing` and :func:`record_exits` in the same pass
    (same sums, same order): (t0, t1 (B,) [s], mark_s (n_lanes,) [m], flat t_arrive,
    t_enter, active, (passing count, sum time, sum length), (the four trip sums), exited).

    Returns (s before, v before, s after, exited) per view vehicle and, with ``record``, the
    (B,) exits of this step (else None); None when numba is missing.
    """
    if not HAVE_NUMBA:
        return None
    c = config
    gate = c.edge_sv_gate
    s_all, v_all, a_all = state
    if record is None:
        t0 = t1 = mark = t_arrive = t_enter = _NO_FLOAT
        active, passing, trips, exited = _NO_BOOL, _NO_PASSING, _NO_TRIPS, _NO_INT
        n_out = None
    else:
        t0, t1, mark, t_arrive, t_enter, active, passing, trips, exited = record
        n_out = np.zeros(exited.size, dtype=np.int64)
    moved, out = _move(
        vehicle, env, lane, sv, d_front, d_back,
        _NO_FLOAT if edge is None else edge, _NO_FLOAT if cloud is None else cloud,
        _NO_BOOL if raw is None else raw, s_all, v_all, a_all, lane_length, sums[0], sums[1],
        float(c.eta), c.end_rule == "sensible", float(c.entry_accel_mps2),
        0.0 if gate is None else float(gate), gate is not None, float(c.omega),
        float(c.a_max_mps2), float(c.velocity_floor_mps), float(c.v_max_mps), float(c.dt_s),
        record is not None, t0, t1, mark, t_arrive, t_enter, active, passing, trips, exited,
        _NO_INT if n_out is None else n_out,
    )
    s_old, v_old, s_new = moved
    return s_old, v_old, s_new, out, n_out


_NO_INT = np.zeros(0, dtype=np.int64)
_NO_PASSING = (_NO_INT, _NO_FLOAT, _NO_FLOAT)
_NO_TRIPS = (_NO_FLOAT, _NO_FLOAT, _NO_FLOAT, _NO_FLOAT)


@njit
def _record_passing(env, lane, vehicle, s_old, s_new, t_enter_all, mark_s, t0, dt, count,
                    sum_time, sum_length):  # pragma: no cover
    bsz = count.size
    n_b = np.zeros(bsz, np.int64)
    time_b = np.zeros(bsz, np.float64)
    length_b = np.zeros(bsz, np.float64)
    for i in range(env.size):
        e = env[i]
        _add_passing(n_b, time_b, length_b, e, mark_s[lane[i]], s_old[i], s_new[i], t0[e], dt,
                     t_enter_all[vehicle[i]])
    for e in range(bsz):
        count[e] += n_b[e]
        sum_time[e] += time_b[e]
        sum_length[e] += length_b[e]


def record_passing(
    env: NDArray[np.int64], lane: NDArray[np.int64], vehicle: NDArray[np.int64],
    s_old: NDArray[np.float64], s_new: NDArray[np.float64], t_enter_all: NDArray[np.float64],
    mark_s: NDArray[np.float64], t0: NDArray[np.float64], dt: float,
    sums: tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]],
) -> bool:
    """``PassingTimes.record`` compiled (``t_enter_all``: the flat (B * capacity,) entry
    times, read at ``vehicle``; ``t0``: (B,) [s]); adds into ``sums`` = the accumulators
    (count, sum_time_s, sum_length_m). False when numba is missing."""
    if not HAVE_NUMBA:
        return False
    _record_passing(env, lane, vehicle, s_old, s_new, t_enter_all, mark_s, t0, float(dt),
                    *sums)
    return True


@njit
def _record_exits(out, env, vehicle, lane, s_old, s_new, lane_length, t0, t1, t_arrive,
                  t_enter, active, sums, exited, n_out):  # pragma: no cover
    # sums: (4, B) travel velocity, travel velocity without the wait, trip time, wait time
    bsz = exited.size
    part = np.zeros((4, bsz), np.float64)
    for i in range(out.size):
        if not out[i]:
            continue
        e = env[i]
        k = vehicle[i]
        length = lane_length[lane[i]]
        _add_exit(part, e, length, _exit_time(length, s_old[i], s_new[i], t0[e], t1[e]),
                  t_arrive[k], t_enter[k])
        n_out[e] += 1
        active[k] = False
    for e in range(bsz):
        for r in range(4):
            sums[r][e] += part[r, e]
        exited[e] += n_out[e]


def record_exits(
    out: NDArray[np.bool_], env: NDArray[np.int64], vehicle: NDArray[np.int64],
    lane: NDArray[np.int64], s_old: NDArray[np.float64], s_new: NDArray[np.float64],
    lane_length: NDArray[np.float64], t0: NDArray[np.float64], t1: NDArray[np.float64],
    t_arrive: NDArray[np.float64], t_enter: NDArray[np.float64], active: NDArray[np.bool_],
    sums: tuple[NDArray[np.float64], ...], exited: NDArray[np.int64],
) -> NDArray[np.int64] | None:
    """``Simulator._record_exits`` compiled: trip sums per environment (``sums`` = the four
    accumulators, added in view order as ``np.bincount`` does), ``exited`` counts, exited
    slots made inactive (``t_arrive``/``t_enter``/``active`` flat). Returns the (B,) exits of
    this step, or None when numba is missing."""
    if not HAVE_NUMBA:
        return None
    n_out = np.zeros(exited.size, dtype=np.int64)
    _record_exits(out, env, vehicle, lane, s_old, s_new, lane_length, t0, t1, t_arrive,
                  t_enter, active, sums, exited, n_out)
    return n_out


@njit
def _box_blocked(asked, s, v, leader, line, box_exit, length, slot, queued_mps,
                 lookahead):  # pragma: no cover
    out = np.empty(asked.size, dtype=np.bool_)
    for j in range(asked.size):
        ahead = leader[asked[j]]
        between = 0
        tail_rear = np.inf
        for _ in range(lookahead):
            if ahead < 0:
                break
            if s[ahead] >= line[j] and v[ahead] < queued_mps:
                tail_rear = s[ahead] - length
                break
            between += 1
            ahead = leader[ahead]
        out[j] = tail_rear - box_exit[j] < (between + 1) * slot
    return out


def box_blocked(
    asked: NDArray[np.int64], s: NDArray[np.float64], v: NDArray[np.float64],
    leader: NDArray[np.int64], line: NDArray[np.float64], box_exit: NDArray[np.float64],
    length: float, slot: float, queued_mps: float, lookahead: int,
) -> NDArray[np.bool_] | None:
    """``signals.box_blocked_reference`` compiled: for each vehicle ``asked`` (view indices),
    whether the room between its box exit (``box_exit`` [m]) and the rear of the first vehicle
    ahead past its stop line (``line`` [m]) slower than ``queued_mps`` [m/s], among
    ``lookahead`` leaders, cannot take the vehicles before that one and itself, ``slot`` [m]
    each. None when numba is missing."""
    if not HAVE_NUMBA:
        return None
    return _box_blocked(asked, s, v, leader, line, box_exit, float(length), float(slot),
                        float(queued_mps), int(lookahead))
