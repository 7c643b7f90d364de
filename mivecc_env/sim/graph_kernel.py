"""Compiled (numba) observation kernels, each identical to the numpy path it replaces.

* :func:`build` fills whole state graphs (head row, channels, reference rows, masks) in one
  pass. For each decision vehicle the numpy path of
  :func:`mivecc_env.sim.state_graph.build_graphs` takes the candidate points on either side of
  its own point on the sorted virtual lane, drops the invalid ones (outside the lane's run or
  the node's area), and orders the rest by :func:`mivecc_env.sim.state_graph.reference_order`
  to keep the K-1 nearest: each half in the view's point order, nearest first, merged by
  distance. This kernel collects the valid points of each half (at most K-1 each) into small
  buffers, reverses every run of equal distances behind the vehicle (increasing point index),
  and merges the two buffers without branches (sentinels of infinite distance end each side),
  stopping after K-1 rows; a tie between the halves goes to the point behind (the lower index).
  The view sorts positions to 0.1 mm, so within 0.1 mm a half keeps the view's order even
  where float noise puts a later point nearer; the numpy path reproduces that order exactly
  (a merge of two sequences is a stable sort by each side's running maximum).
* :func:`select_per_group`: the K lowest keys per group (stable top-K by insertion).
* :func:`density_indicator`, :func:`area_centres`, :func:`control_area`: loops replacing a few
  numpy calls each.

The features are the same float operations in the same order (no fast-math), so results are
bit-identical (tested in ``tests/sim/test_graph_kernel.py`` and
``tests/env/test_reward_kernel.py``).
"""

from __future__ import annotations

import numpy as np

from mivecc_env.sim._numba import HAVE_NUMBA, njit

__all__ = [
    "HAVE_NUMBA", "build", "control_area_before", "select_capped_desc", "select_cloud_di",
    "select_nodes", "select_per_group",
]

#: Index cast for the hot loops: numba wraps a negative signed index around (a sign test per
#: access); an unsigned index skips it. Only for indices known to be >= 0.
U = np.uint64


@njit
def _channel(x):  # pragma: no cover - compiled
    return np.float32(min(max(x, -1.0), 1.0))


@njit
def _channels(velocity, accel, v_lo, v_mul, a_mul):  # pragma: no cover - compiled
    """(n, 2) float32 velocity and acceleration channels of every view vehicle."""
    va = np.empty((velocity.shape[0], 2), np.float32)
    for i in range(velocity.shape[0]):
        va[i, 0] = _channel((velocity[i] - v_lo) * v_mul - 1.0)
        va[i, 1] = _channel(accel[i] * a_mul)
    return va



@njit
def _build(cells, mask, slot, view_index, refs, k, decision, node, column, view_s, view_lane,
           view_vehicle, own_point, run_start, run_end, point_pos, point_vehicle, velocity,
           accel, v_lo, v_mul, a_mul, lane_cp_s, lane_length, use_area, centre, n_area,
           lane_intersections, lane_centres_s, radius, inv_scale):  # pragma: no cover - compiled
    for j in range(mask.shape[0]):  # every column empty, then the decisions' columns
        mask[j] = 0.0
        slot[j] = -1
        view_index[j] = -1
    va = _channels(velocity, accel, v_lo, v_mul, a_mul)
    b_idx = np.empty(k + 1, np.int64)  # valid candidates behind / ahead of one decision
    b_dist = np.empty(k + 1, np.float64)  # (+ a sentinel)
    a_idx = np.empty(k + 1, np.int64)
    a_dist = np.empty(k + 1, np.float64)
    want_refs = refs.shape[0] > 0
    for i in range(decision.shape[0]):
        d = decision[i]
        s = view_s[d]
        lane = view_lane[d]
        if want_refs:
            for r in range(k - 1):
                refs[i * (k - 1) + r] = -1
        c = 0.0
        if use_area:
            if n_area > 0:  # the centre of area node % n_area on the lane (_area_centres)
                area = node[i] % n_area
                which = 0
                for j in range(lane_intersections.shape[1]):
                    if lane_intersections[lane, j] == area:
                        which = j
                        break
                c = lane_centres_s[lane, which]
            else:
                c = centre[i]
        # row 0: distance to the next conflict point ahead (the lane end past the last one)
        stop = np.inf
        for cp in lane_cp_s[lane]:
            if cp >= s and cp < stop:
                stop = cp
        if not np.isfinite(stop):
            stop = lane_length[lane]
        head = node[i] * (k * k) + column[i]
        flat = node[i] * k + column[i]
        if mask[flat] != 0.0:
            raise ValueError("build: two decisions in one (node, column)")
        cells[head, 0] = _channel((s - stop) * inv_scale)
        cells[head, 1] = va[d, 0]
        cells[head, 2] = va[d, 1]
        mask[flat] = 1.0
        slot[flat] = view_vehicle[d]
        view_index[flat] = d
        # rows 1..K-1: merge the valid points behind and ahead, nearest first. Candidates
        # are kept without a branch (stored, then counted if valid).
        p = own_point[d]
        lo = max(run_start[p], p - (k - 1))
        hi = min(run_end[p], p + k)  # exclusive
        nb = 0
        if use_area:
            for q in range(p - 1, lo - 1, -1):  # valid points behind, nearest (highest) first
                x = point_pos[U(q)]
                b_idx[U(nb)] = q
                b_dist[U(nb)] = abs(x - s)
                nb += abs(x - c) <= radius
        else:
            for q in range(p - 1, lo - 1, -1):
                b_idx[U(nb)] = q
                b_dist[U(nb)] = abs(point_pos[U(q)] - s)
                nb += 1
        # a run of equal distances behind goes out in increasing point index
        t = 0
        while t < nb - 1:
            if b_dist[t + 1] != b_dist[t]:
                t += 1
                continue
            e = t + 1
            while e + 1 < nb and b_dist[e + 1] == b_dist[t]:
                e += 1
            lo_t, hi_t = t, e
            while lo_t < hi_t:
                b_idx[lo_t], b_idx[hi_t] = b_idx[hi_t], b_idx[lo_t]
                lo_t += 1
                hi_t -= 1
            t = e + 1
        na = 0
        if use_area:
            for q in range(p + 1, hi):  # valid points ahead, nearest (lowest) first
                x = point_pos[U(q)]
                a_idx[U(na)] = q
                a_dist[U(na)] = abs(x - s)
                na += abs(x - c) <= radius
        else:
            for q in range(p + 1, hi):
                a_idx[U(na)] = q
                a_dist[U(na)] = abs(point_pos[U(q)] - s)
                na += 1
        b_dist[nb] = np.inf  # sentinels: an exhausted side never wins
        b_idx[nb] = p
        a_dist[na] = np.inf
        a_idx[na] = p
        # merge by distance (a tie goes to the point behind, the lower index), branch-free
        ib = 0
        ia = 0
        cell = head + k
        for r in range(min(k - 1, nb + na)):
            take_b = np.int64(b_dist[U(ib)] <= a_dist[U(ia)])
            qa = a_idx[U(ia)]
            q = qa + take_b * (b_idx[U(ib)] - qa)
            ib += take_b
            ia += 1 - take_b
            veh = point_vehicle[U(q)]
            if want_refs:
                refs[i * (k - 1) + r] = veh
            uc = U(cell)
            cells[uc, 0] = _channel((point_pos[U(q)] - s) * inv_scale)
            cells[uc, 1] = va[U(veh), 0]
            cells[uc, 2] = va[U(veh), 1]
            cell += k
        while cell < head + k * k:  # rows past the references: zero padding
            cells[cell, 0] = 0.0
            cells[cell, 1] = 0.0
            cells[cell, 2] = 0.0
            cell += k
    for flat in range(mask.shape[0]):  # columns without a decision: zero padding
        if mask[flat] == 0.0:
            head = (flat // k) * (k * k) + flat % k
            for cell in range(head, head + k * k, k):
                cells[cell, 0] = 0.0
                cells[cell, 1] = 0.0
                cells[cell, 2] = 0.0


def build(
    cells: np.ndarray, mask: np.ndarray, slot: np.ndarray, view_index: np.ndarray, k: int,
    decision: np.ndarray, node: np.ndarray, column: np.ndarray, view, velocity: np.ndarray,
    accel: np.ndarray, v_lo: float, v_mul: float, a_mul: float, lane_cp_s: np.ndarray,
    lane_length: np.ndarray, centre: np.ndarray | tuple | None, radius: float,
    inv_scale: float, refs: np.ndarray | None = None,
) -> None:
    """Fill every decision's column of the state graphs (all rows) and its mask entries.

    Args:
        cells: (N*K*K, 3) float32, cell ``(node, row, column)`` at
            ``(node * K + row) * K + column``; overwritten whole (zeros where nothing), so it
            may come uninitialised.
        mask / slot / view_index: (N*K,) flat outputs, overwritten whole (0 / -1 / -1 where
            no decision; they may come uninitialised).
        decision / node / column: (D,) the selected view vehicles, their node and column
            (each ``(node, column)`` at most once: ``ValueError`` otherwise).
        view: the :class:`~mivecc_env.sim.virtual_lane.VirtualLaneView`.
        velocity / accel: (n,) per view vehicle [m/s], [m/s^2].
        v_lo / v_mul / a_mul: velocity channel ``(v - v_lo) * v_mul - 1``, accel ``a * a_mul``.
        lane_cp_s / lane_length: the network's conflict points per lane (inf padding) and
            lane lengths [m].
        centre / radius: area filter of the references [m]: ``None`` (no filter), (D,) the
            centre of each decision's area on its lane, or ``(n_area, lane_intersections,
            lane_centres_s)``: the area is intersection ``node % n_area``, its centre looked
            up on the decision's lane in the kernel (as :func:`area_centres` does).
        inv_scale: 1 / position scale [1/m].
        refs: optional (D * (K-1),) int64 output: the view index of each decision's reference
            rows, nearest first, -1 for padding (decision ``i``'s at ``i * (K-1) + row - 1``).
    """
    use_area = centre is not None
    n_area, inter, centres = 0, _NO_INT2, _NO_FLOAT2
    c = _NO_FLOAT
    if isinstance(centre, tuple):
        n_area, inter, centres = centre
        n_area = int(n_area)
    elif use_area:
        c = centre
    _build(cells, mask, slot, view_index, _NO_INT if refs is None else refs, k, decision, node,
           column, view.s, view.lane,
           view.vehicle, view.own_point, view.point_run_start, view.point_run_end,
           view.point_pos, view.point_vehicle, velocity, accel, float(v_lo), float(v_mul),
           float(a_mul), lane_cp_s, lane_length, use_area, c, n_area, inter, centres,
           float(radius), float(inv_scale))


_NO_FLOAT = np.zeros(0)
_NO_INT = np.zeros(0, dtype=np.int64)
_NO_FLOAT2 = np.zeros((0, 0))
_NO_INT2 = np.zeros((0, 0), dtype=np.int64)


@njit
def _less(a, b):  # pragma: no cover - compiled
    """``a`` sorts before ``b`` (NaN last, like numpy's sorts; equal keys: neither)."""
    return a < b or (b != b and a == a)


#: Buckets of :func:`_bucket_prefilter`.
_N_BUCKETS = 64


@njit
def _bucket_prefilter(members, key, k, hist, order):  # pragma: no cover - compiled
    """The members that can be among the ``k`` lowest keys, in (key bucket, index) order.

    Buckets split ``[min, max]`` of the finite keys evenly (NaN: one bucket after them); a
    bucket is a non-decreasing function of the key, so equal keys share a bucket and keep
    their index order, and every member of a bucket past the one holding the k-th lowest key
    has a larger key than the k lowest. Returns ``members`` unchanged if a key is infinite.
    """
    n = members.shape[0]
    lo = np.inf
    hi = -np.inf
    for t in range(n):
        x = key[U(members[U(t)])]
        if x == np.inf or x == -np.inf:
            return members
        if x < lo:
            lo = x
        if x > hi:
            hi = x
    nb = _N_BUCKETS
    scale = 0.0
    if hi > lo:
        scale = nb / (hi - lo)
        if not np.isfinite(scale):
            return members
    for j in range(nb + 2):
        hist[j] = 0
    for t in range(n):
        x = key[U(members[U(t)])]
        b = nb + 1  # NaN
        if x == x:
            b = min(np.int64((x - lo) * scale), nb - 1)
        hist[U(b)] += 1
    top = 0  # the bucket holding the k-th lowest key
    total = hist[0]
    while total < k:
        top += 1
        total += hist[U(top)]
    start = 0  # bucket offsets (exclusive prefix sums) of buckets 0..top
    for j in range(top + 1):
        c = hist[U(j)]
        hist[U(j)] = start
        start += c
    for t in range(n):
        i = members[U(t)]
        x = key[U(i)]
        b = nb + 1
        if x == x:
            b = min(np.int64((x - lo) * scale), nb - 1)
        if b <= top:
            order[U(hist[U(b)])] = i
            hist[U(b)] += 1
    return order[:start]


@njit
def _select(group, key, n_groups, k):  # pragma: no cover - compiled
    """(3, n_out) rows (index, group, column) of the selection (one array: each array a
    kernel returns costs a boxing call)."""
    n = group.shape[0]
    count = np.zeros(n_groups + 1, np.int64)
    for i in range(n):
        if group[i] >= 0:
            count[group[i] + 1] += 1
    n_out = 0
    for g in range(n_groups):
        n_out += min(k, count[g + 1])
        count[g + 1] += count[g]
    start = count.copy()
    members = np.empty(count[n_groups], np.int64)
    for i in range(n):  # counting sort by group: index order within a group
        g = group[i]
        if g >= 0:
            members[start[g]] = i
            start[g] += 1
    out = np.empty((3, n_out), np.int64)
    out_idx = out[0]
    out_group = out[1]
    out_col = out[2]
    buf_key = np.empty(max(k, 1), np.float64)
    buf_idx = np.empty(max(k, 1), np.int64)
    hist = np.zeros(_N_BUCKETS + 2, np.int64)
    order = np.empty(members.shape[0], np.int64)
    m_out = 0
    for g in range(n_groups):
        first, last = count[g], count[g + 1]
        seq = members[first:last]
        if last - first > 2 * k:
            seq = _bucket_prefilter(members[first:last], key, k, hist, order)
        # the k lowest keys of the group, kept sorted by insertion; members come in index
        # order (or bucket then index order) and an equal key never moves ahead, so ties
        # keep index order (a stable sort)
        m = 0
        for t in range(seq.shape[0]):
            i = seq[U(t)]
            x = key[U(i)]
            if m == k:
                if not _less(x, buf_key[U(k - 1)]):
                    continue
            else:
                m += 1
            pos = m - 1
            while pos > 0 and _less(x, buf_key[U(pos - 1)]):
                buf_key[U(pos)] = buf_key[U(pos - 1)]
                buf_idx[U(pos)] = buf_idx[U(pos - 1)]
                pos -= 1
            buf_key[U(pos)] = x
            buf_idx[U(pos)] = i
        for c in range(m):
            out_idx[m_out] = buf_idx[c]
            out_group[m_out] = g
            out_col[m_out] = c
            m_out += 1
    return out


@njit
def _select_nodes(env, area, n_per_env, key, k):  # pragma: no cover - compiled
    """:func:`_select` with ``group = env * n_per_env + area`` (-1 where ``area < 0``) and
    ``n_groups = (max(env) + 1) * n_per_env`` computed here."""
    n = env.shape[0]
    group = np.empty(n, np.int64)
    top = -1
    for i in range(n):
        group[i] = env[i] * n_per_env + area[i] if area[i] >= 0 else -1
        if env[i] > top:
            top = env[i]
    return _select(group, key, (top + 1) * n_per_env if n else 0, k)


@njit
def _select_capped_desc(env, eligible, value, cap, k):  # pragma: no cover - compiled
    """:func:`_select` of the ``k`` highest ``min(value, cap)`` per environment among the
    ``eligible`` vehicles (all if ``eligible`` is empty): the key is ``-np.minimum(value,
    cap)`` (NaN stays NaN) and the group the environment (-1 where not eligible)."""
    n = env.shape[0]
    group = np.empty(n, np.int64)
    key = np.empty(n, np.float64)
    use = eligible.shape[0] > 0
    top = -1
    for i in range(n):
        group[i] = env[i] if (not use or eligible[i]) else -1
        x = value[i]
        key[i] = -(x if (x < cap or x != x) else cap)
        if env[i] > top:
            top = env[i]
    return _select(group, key, top + 1 if n else 0, k)


def select_per_group(
    group: np.ndarray, key: np.ndarray, n_groups: int, k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Up to ``k`` elements of lowest ``key`` per group (ties: lower index first).

    Same result as a stable sort on ``(group, key)`` keeping the first ``k`` of each group.

    Args:
        group: (n,) int64 group of each element in ``[0, n_groups)``, -1 to leave it out.
        key: (n,) float64.

    Returns:
        (index, group, column) of each selected element, by group then column.
    """
    idx, grp, col = _select(group, key, n_groups, k)
    return idx, grp, col


def select_nodes(
    env: np.ndarray, area: np.ndarray, n_per_env: int, key: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`select_per_group` with ``group = env * n_per_env + area`` (left out where
    ``area < 0``) and ``n_groups = (max(env) + 1) * n_per_env`` (0 if empty), in one call."""
    idx, grp, col = _select_nodes(env, area, int(n_per_env), key, int(k))
    return idx, grp, col


_NO_BOOL = np.zeros(0, dtype=np.bool_)


def select_capped_desc(
    env: np.ndarray, eligible: np.ndarray | None, value: np.ndarray, cap: float, k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`select_per_group` with ``key = -np.minimum(value, cap)`` and ``group = env``
    (left out where not ``eligible``; all eligible if None), ``n_groups = max(env) + 1``:
    the ``k`` highest capped values per environment, in one call."""
    idx, grp, col = _select_capped_desc(env, _NO_BOOL if eligible is None else eligible,
                                        value, float(cap), int(k))
    return idx, grp, col


@njit
def _area_centres(lane, area, lane_intersections, lane_centres_s):  # pragma: no cover
    out = np.empty(lane.shape[0], np.float64)
    for i in range(lane.shape[0]):
        which = 0  # argmax of an all-False row is 0
        for j in range(lane_intersections.shape[1]):
            if lane_intersections[lane[i], j] == area[i]:
                which = j
                break
        out[i] = lane_centres_s[lane[i], which]
    return out


def area_centres(
    lane: np.ndarray, area: np.ndarray, lane_intersections: np.ndarray,
    lane_centres_s: np.ndarray,
) -> np.ndarray:
    """(D,) position [m] on ``lane`` of the centre of intersection ``area`` (the first of the
    lane's intersections equal to it; the lane's first centre if none is)."""
    return _area_centres(lane, area, lane_intersections, lane_centres_s)


@njit
def _di_of(p, run_start, run_end, point_pos, n):  # pragma: no cover - compiled
    """Density indicator of the vehicle whose own point is ``p`` (one formula for
    :func:`_density_indicator` and :func:`_select_cloud_di`)."""
    start, end = run_start[p], run_end[p]
    count = end - start
    if count < 2:
        return 0.0
    ahead = min(p + n, end - 1)
    behind = max(p - n, start)
    local = abs(point_pos[ahead] - point_pos[behind]) / max(ahead - behind, 1)
    mean = abs(point_pos[end - 1] - point_pos[start]) / max(count - 1, 1)
    return abs(local - mean)


@njit
def _density_indicator(own_point, run_start, run_end, point_pos, n):  # pragma: no cover
    out = np.empty(own_point.shape[0], np.float64)
    for i in range(own_point.shape[0]):
        out[i] = _di_of(own_point[i], run_start, run_end, point_pos, n)
    return out


@njit
def _select_cloud_di(env, eligible, own_point, run_start, run_end, point_pos, n, cap,
                     k):  # pragma: no cover - compiled
    """:func:`_select_capped_desc` of the density indicator (computed here, only for the
    eligible vehicles: the others are never ranked, so their 0 is never read)."""
    m = env.shape[0]
    di = np.zeros(m, np.float64)
    use = eligible.shape[0] > 0
    for i in range(m):
        if not use or eligible[i]:
            di[i] = _di_of(own_point[i], run_start, run_end, point_pos, n)
    return _select_capped_desc(env, eligible, di, cap, k)


def select_cloud_di(
    env: np.ndarray, eligible: np.ndarray | None, own_point: np.ndarray,
    run_start: np.ndarray, run_end: np.ndarray, point_pos: np.ndarray, n: int, cap: float,
    k: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`select_capped_desc` of ``value = density_indicator(view, n)`` (the view's
    ``own_point``, ``point_run_start``, ``point_run_end``, ``point_pos``) in one call, the
    indicator computed only for the ``eligible`` vehicles (identical results)."""
    idx, grp, col = _select_cloud_di(env, _NO_BOOL if eligible is None else eligible,
                                     own_point, run_start, run_end, point_pos, int(n),
                                     float(cap), int(k))
    return idx, grp, col


def density_indicator(
    own_point: np.ndarray, run_start: np.ndarray, run_end: np.ndarray, point_pos: np.ndarray,
    n: int,
) -> np.ndarray:
    """Compiled :func:`mivecc_env.sim.virtual_lane.density_indicator` (same arguments taken
    from the view; identical results)."""
    return _density_indicator(own_point, run_start, run_end, point_pos, int(n))


@njit
def _area_of(lane, s, lane_centres_s, lane_intersections, radius, seg):  # pragma: no cover
    """Control area of one point (one formula for :func:`_control_area` and
    :func:`_control_area_before`)."""
    k = np.int64(np.floor((s + radius) / seg)) - 1
    k = min(max(k, 0), lane_centres_s.shape[1] - 1)
    centre = lane_centres_s[lane, k]
    inside = s >= centre - radius and s < centre + radius
    return lane_intersections[lane, k] if inside else -1


@njit
def _control_area(lane, s, lane_centres_s, lane_intersections, radius, seg):  # pragma: no cover
    out = np.empty(lane.shape[0], np.int64)
    for i in range(lane.shape[0]):
        out[i] = _area_of(lane[i], s[i], lane_centres_s, lane_intersections, radius, seg)
    return out


@njit
def _control_area_before(lane, s, lane_centres_s, lane_intersections, radius, seg,
                         limit_s):  # pragma: no cover - compiled
    area = np.empty(lane.shape[0], np.int64)
    before = np.empty(lane.shape[0], np.bool_)
    for i in range(lane.shape[0]):
        area[i] = _area_of(lane[i], s[i], lane_centres_s, lane_intersections, radius, seg)
        before[i] = s[i] < limit_s[lane[i]]
    return area, before


def control_area_before(
    lane: np.ndarray, s: np.ndarray, lane_centres_s: np.ndarray,
    lane_intersections: np.ndarray, radius: float, seg: float, limit_s: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`control_area` and ``s < limit_s[lane]`` (the cloud's pick population,
    ``state_graph.cloud_population`` with ``population_limit_s``) in one pass over the
    points (identical results)."""
    return _control_area_before(lane, s, lane_centres_s, lane_intersections, float(radius),
                                float(seg), limit_s)


def control_area(
    lane: np.ndarray, s: np.ndarray, lane_centres_s: np.ndarray,
    lane_intersections: np.ndarray, radius: float, seg: float,
) -> np.ndarray:
    """Compiled :meth:`mivecc_env.sim.network.GridNetwork.control_area` of 1-D arrays
    (identical results)."""
    return _control_area(lane, s, lane_centres_s, lane_intersections, float(radius), float(seg))
