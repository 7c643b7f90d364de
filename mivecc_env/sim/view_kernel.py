"""Compiled (numba) build of the virtual-lane view: the same result as the numpy reference.

:func:`build_view_fast` returns exactly (bit for bit, element for element) what
:func:`mivecc_env.sim.virtual_lane.build_view_reference` returns, in one compiled kernel
(:func:`_build`) that handles one environment after the other (the reference's sort key
``(group, position quantised to 0.1 mm, point index)`` with ``group = env * n_lanes + lane``
is environment-major, so the sorted view is the environments' sorted parts one after the
other):

1. the environment's active vehicles and their projections (the reference's point order:
   own points in slot order, then projections by vehicle and conflict column), each point's
   key ``(lane, position quantised, local point index)`` packed into one unique ``int64``
   (the local index keeps the reference's tie order: input order);
2. a counting sort of the keys by bucket (the key's top bits: the lane and the position's
   top bits, one to two buckets per point) and an insertion sort, which moves keys only
   within their bucket (a few each): exactly the order of the reference's stable radix
   sort, ties included;
3. the runs (one per lane: the lane's buckets), the sorted point arrays, then every
   vehicle's front and back point and distances and its own-lane leader and follower from
   its own point and the own points next to it.

Everything one environment touches at random (its scratch arrays and its part of the view)
fits in the first-level cache. Only integer work, comparisons and the reference's own float
additions and subtractions (same operands, same order, no fast-math) happen in the kernel, so
results are identical. When numba is not installed, or when a batch is too large for the
packed key (the reference then falls back to a float argsort), :func:`build_view_fast` returns
None and the caller uses the reference. Set ``MIVECC_NO_NUMBA=1`` to force the reference path.
"""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from mivecc_env.sim._numba import HAVE_NUMBA, njit

if TYPE_CHECKING:
    from mivecc_env.sim.network import GridNetwork
    from mivecc_env.sim.virtual_lane import VirtualLaneView


#: Rows of the view's blocks (see :func:`_allocate`) and of the scratch arrays (see
#: :func:`_scratch`); numba compiles them as constants.
_VEHICLE, _ENV, _LANE, _OWN_POINT, _FRONT, _BACK, _LEADER, _FOLLOWER = range(8)  # vi
_S, _D_FRONT, _D_BACK = range(3)  # vf
_GROUP, _POINT_VEHICLE, _RUN_START, _RUN_END = range(4)  # pi
_KEY, _SORTED, _SRC, _OWN = range(4)  # li
_POS = 0  # lf
#: Indices are cast to unsigned where the compiler cannot prove them non-negative: numba
#: then skips the negative-index wraparound (a large share of the kernel's instructions).
_U = np.uint64


@njit
def _build(active, lane, s, lane_cp_s, lane_cp_other_lane, lane_cp_other_s, window_m, clear_m,
           centre_at, candidate, n_lanes, q_scale, qbits, lbits, qdrop, li, lf, counts,
           lane_end, vi, vf, pi, pf, pb):  # pragma: no cover
    """The whole view, one environment after the other (see the module docstring).

    ``li``/``lf``/``counts``/``lane_end``: the scratch arrays of :func:`_scratch` (rows:
    keys, sorted keys, vehicles, own points / positions; bucket counts; each lane's end in
    the sorted points); ``vi``, ``vf``, ``pi``, ``pf``,
    ``pb``: the view's blocks of :func:`_allocate` (rows as in ``_FIELDS``), with room for
    every vehicle and point. Writes them and returns (vehicles, points, every key in range).
    """
    bsz, cap = active.shape
    n_col = 2 if candidate else lane_cp_s.shape[1]
    qmax = (np.int64(1) << qbits) - 1
    shift_l = qbits + lbits
    lmask = (np.int64(1) << lbits) - 1
    bad = False
    n = 0  # vehicles so far
    out = 0  # points so far
    for b in range(bsz):
        # 1. vehicles and points of environment b, their keys
        v0 = n
        m = 0
        for k in range(cap):
            if active[b, k]:
                x = s[b, k]
                ln = lane[b, k]
                un, um = _U(n), _U(m)
                vi[_VEHICLE, un] = b * cap + k
                vi[_ENV, un] = b
                vi[_LANE, un] = ln
                vf[_S, un] = x
                lf[_POS, um] = x
                li[_SRC, um] = m
                q = np.int64((x + window_m) * q_scale)
                bad |= (q > qmax) | (q < 0)
                li[_KEY, um] = (ln << shift_l) | (min(max(q, 0), qmax) << lbits) | m
                n += 1
                m += 1
        nv = m
        for iv in range(nv):
            ln = _U(vi[_LANE, _U(v0 + iv)])
            x = vf[_S, _U(v0 + iv)]
            c0 = 0
            if candidate:  # only the two conflict points of the one intersection in range
                for t in range(centre_at.size):  # the centre index (see _centre_thresholds)
                    c0 += 2 * np.int64(x >= centre_at[t])
            for c in range(c0, c0 + n_col):
                uc = _U(c)
                delta = x - lane_cp_s[ln, uc]
                if delta >= -window_m and delta <= clear_m:
                    y = lane_cp_other_s[ln, uc] + delta
                    um = _U(m)
                    lf[_POS, um] = y
                    li[_SRC, um] = iv
                    q = np.int64((y + window_m) * q_scale)
                    bad |= (q > qmax) | (q < 0)
                    li[_KEY, um] = ((lane_cp_other_lane[ln, uc] << shift_l)
                                    | (min(max(q, 0), qmax) << lbits) | m)
                    m += 1
        # 2. sort: counting sort by bucket (one to two per point), then insertion sort within
        # the buckets
        qd = qdrop
        while qd < qbits and n_lanes << (qbits - qd) > max(2 * m, n_lanes):
            qd += 1
        bshift = lbits + qd
        nb = n_lanes << (qbits - qd)
        counts[:nb] = 0
        for t in range(m):
            counts[_U(li[_KEY, t] >> bshift)] += 1
        total = 0
        for t in range(nb):
            c = counts[t]
            counts[t] = total
            total += c
        for t in range(m):
            key = li[_KEY, t]
            ub = _U(key >> bshift)
            d = counts[ub]
            counts[ub] = d + 1
            li[_SORTED, _U(d)] = key
        if m > 0:  # one branch-free bubble pass: a pair of points in a bucket comes out sorted
            hi = li[_SORTED, 0]
            for t in range(1, m):
                key = li[_SORTED, t]
                li[_SORTED, _U(t - 1)] = min(hi, key)
                hi = max(hi, key)
            li[_SORTED, _U(m - 1)] = hi
        for t in range(1, m):  # what the bubble pass left (bigger buckets: rare)
            key = li[_SORTED, t]
            if li[_SORTED, _U(t - 1)] > key:
                u = t
                while u > 0 and li[_SORTED, _U(u - 1)] > key:
                    li[_SORTED, _U(u)] = li[_SORTED, _U(u - 1)]
                    u -= 1
                li[_SORTED, _U(u)] = key
        # 3. the environment's part of the view: runs (one per lane: its buckets), points,
        # then the vehicles from their own points (in sorted order)
        bb = qbits - qd  # bucket bits per lane
        g0 = b * n_lanes
        a = 0
        for ln in range(n_lanes):
            e = counts[_U(((ln + 1) << bb) - 1)]  # end of the lane's last bucket
            lane_end[ln] = e
            for r in range(_U(out + a), _U(out + e)):
                pi[_GROUP, r] = g0 + ln
                pi[_RUN_START, r] = out + a
                pi[_RUN_END, r] = out + e
            a = e
        k = 0
        for r in range(m):
            jl = li[_SORTED, r] & lmask
            ur = _U(out + r)
            pf[ur] = lf[_POS, _U(jl)]
            pi[_POINT_VEHICLE, ur] = v0 + li[_SRC, _U(jl)]
            is_own = jl < nv
            pb[ur] = is_own
            li[_OWN, _U(k)] = r  # kept where the point is own (no data-dependent branch)
            k += np.int64(is_own)
        ln = 0
        a = 0  # the current lane's run: [a, e)
        e = lane_end[0]
        last = out + m - 1
        prev_r = -1  # the previous own point and its vehicle
        prev_i = 0
        for k in range(nv):
            r = li[_OWN, k]
            i = v0 + (li[_SORTED, _U(r)] & lmask)
            ui = _U(i)
            while r >= e:  # the next lane with points
                ln += 1
                a = e
                e = lane_end[_U(ln)]
            same = prev_r >= a  # the previous own point is on this lane: the follower
            vi[_FOLLOWER, ui] = prev_i if same else -1
            if k > 0:
                vi[_LEADER, _U(prev_i)] = i if same else -1
            R = out + r
            x = pf[_U(R)]
            yb = pf[_U(max(R - 1, out))]
            yf = pf[_U(min(R + 1, last))]
            vi[_OWN_POINT, ui] = R
            vi[_BACK, ui] = R - 1 if r > a else -1
            vf[_D_BACK, ui] = x - yb if r > a else np.inf
            vi[_FRONT, ui] = R + 1 if r + 1 < e else -1
            vf[_D_FRONT, ui] = yf - x if r + 1 < e else np.inf
            prev_r = r
            prev_i = i
        if nv > 0:
            vi[_LEADER, _U(prev_i)] = -1
        out += m
    return n, out, not bad


def _bits(x: int) -> int:
    return max(1, int(x).bit_length())


#: The view's arrays are rows of five blocks (fewer arrays for the kernel to address):
#: (block, row) of every field of :class:`~mivecc_env.sim.virtual_lane.VirtualLaneView`.
_FIELDS = (
    ("vehicle", "vi", _VEHICLE), ("env", "vi", _ENV), ("lane", "vi", _LANE), ("s", "vf", _S),
    ("point_group", "pi", _GROUP), ("point_pos", "pf", None),
    ("point_vehicle", "pi", _POINT_VEHICLE), ("point_own", "pb", None),
    ("point_run_start", "pi", _RUN_START), ("point_run_end", "pi", _RUN_END),
    ("own_point", "vi", _OWN_POINT), ("front_point", "vi", _FRONT), ("back_point", "vi", _BACK),
    ("d_front", "vf", _D_FRONT), ("d_back", "vf", _D_BACK), ("leader", "vi", _LEADER),
    ("follower", "vi", _FOLLOWER),
)
_PER_POINT = ("pi", "pf", "pb")


def _allocate(n_vehicles: int, n_points: int) -> dict:
    """The blocks of one view: vehicle int64 rows and float64 rows (room for ``n_vehicles``),
    point int64 rows, positions and own flags (room for ``n_points``); ``"fields"``: each
    field's whole row and whether it is per point, in the order of ``_FIELDS``."""
    bufs = {"vi": np.empty((8, n_vehicles), np.int64), "vf": np.empty((3, n_vehicles)),
            "pi": np.empty((4, n_points), np.int64), "pf": np.empty(n_points),
            "pb": np.empty(n_points, np.bool_)}
    bufs["fields"] = [(bufs[block] if row is None else bufs[block][row], block in _PER_POINT)
                      for _name, block, row in _FIELDS]
    return bufs


def _scratch(n_points: int, n_buckets: int, n_lanes: int) -> tuple[np.ndarray, ...]:
    """The per-environment scratch arrays of :func:`_build`: keys, sorted keys, vehicles, own
    points (int64 rows) and positions (room for ``n_points``), the bucket counts and the
    lanes' ends."""
    return (np.empty((4, n_points), np.int64), np.empty((1, n_points)),
            np.empty(n_buckets, np.int64), np.empty(n_lanes, np.int64))


class ViewWorkspace:
    """Reusable output buffers of :func:`build_view_fast`, owned by one caller.

    The compiled build writes into these buffers instead of returning fresh arrays (each
    array a numba kernel returns costs a Python-side boxing call). The view of a call is
    made of slices of one of two buffer sets used in turn, so the view returned by the
    previous call stays intact while the next one is built; the view two builds back is
    overwritten. Use it only where no view outlives the next build: the simulator's own view
    (``Simulator.view``, rebuilt by every ``step`` and ``reset_at``; the simulator copies the
    one array it keeps for the next step). Buffers grow (never shrink) to the largest batch
    seen.
    """

    def __init__(self) -> None:
        self._sets: list[dict] = [{}, {}]
        self._turn = 0
        #: arguments and result of the last ``_layout`` (the key layout of the batch shape)
        self.layout_key: tuple | None = None
        self.layout: tuple[int, int, int, int, np.ndarray] | None = None
        #: per-environment scratch arrays of the build (see :func:`_scratch`)
        self.scratch: tuple[np.ndarray, ...] = _scratch(0, 0, 0)

    def take(self, n_vehicles: int, n_points: int) -> dict:
        """The next buffer set, with room for ``n_vehicles`` vehicles and ``n_points``
        points."""
        self._turn ^= 1
        bufs = self._sets[self._turn]
        if not bufs or bufs["vi"].shape[1] < n_vehicles or bufs["pf"].size < n_points:
            bufs = _allocate(n_vehicles, n_points)
            self._sets[self._turn] = bufs
        return bufs

    def take_scratch(self, n_points: int, n_buckets: int, n_lanes: int,
                     ) -> tuple[np.ndarray, ...]:
        """The scratch arrays, with room for ``n_points`` points of one environment and
        exactly ``n_buckets`` bucket counts and ``n_lanes`` lanes."""
        if (self.scratch[1].shape[1] < n_points or self.scratch[2].size != n_buckets
                or self.scratch[3].size != n_lanes):
            self.scratch = _scratch(n_points, n_buckets, n_lanes)
        return self.scratch


def _centre_index(x: float, seg: float, off: float, clear_m: float, n_on: int) -> int:
    """The reference's candidate centre index of a position ``x`` [m] (see
    ``virtual_lane._candidate_conflict_columns``), with its float64 operations."""
    k = int(np.ceil((np.float64(x) - clear_m - off) / seg)) - 1
    return min(max(k, 0), n_on - 1)


@lru_cache(maxsize=64)
def _centre_thresholds(seg: float, off: float, clear_m: float, n_on: int) -> np.ndarray:
    """The least float64 position at which the candidate centre index reaches 1, 2, ...,
    ``n_on - 1`` [m]: the index is then the number of thresholds at or below a position.
    Cached per geometry (a read-only array): callers without a workspace rebuild the layout
    on every call, and the bisection costs about 0.5 ms.

    The index is a non-decreasing function of the position (each float operation is
    monotone), so a bisection over the ordered bit patterns of the non-negative doubles
    finds each threshold exactly; positions below 0 have index 0.
    """
    out = np.empty(max(n_on - 1, 0))
    for k in range(1, n_on):
        lo = 0  # bit pattern of 0.0: index below k
        hi = int(np.float64(np.inf).view(np.int64))  # index n_on - 1 >= k at +inf
        if _centre_index(0.0, seg, off, clear_m, n_on) >= k:
            out[k - 1] = -np.inf
            continue
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if _centre_index(float(np.int64(mid).view(np.float64)), seg, off, clear_m,
                             n_on) >= k:
                hi = mid
            else:
                lo = mid
        out[k - 1] = np.int64(hi).view(np.float64)
    out.flags.writeable = False
    return out


def _layout(
    network: GridNetwork, window_m: float, clear_m: float, bsz: int, cap: int, q_scale: float,
    candidate: bool,
) -> tuple[int, int, int, int, np.ndarray] | None:
    """(conflict columns tested per vehicle, position bits, local point-index bits, position
    bits dropped in the sort's bucket index, the candidate centre thresholds of
    :func:`_centre_thresholds`) of the packed key, or None where the reference would not
    use its radix sort (its float argsort may order ties otherwise).

    A bucket of the sort is the key's top bits: the lane and the position's top bits, about
    one to two buckets per point of the environment (at least one per lane; :func:`_build`
    drops more position bits for an environment with fewer points); ``qdrop`` is the least
    number of position bits dropped (the most buckets: twice the points one environment can
    hold).
    """
    n_groups = bsz * network.n_lanes
    if n_groups > 1 << 16:  # the reference sorts such batches with a float argsort
        return None
    n_col = 2 if candidate else network.lane_cp_s.shape[1]
    reach = float(network.lane_length.max()) + clear_m + window_m
    qbits = _bits(int(reach * q_scale * 1.001) + 2)
    per_env = cap * (1 + n_col)
    lbits = _bits(per_env)
    if qbits > 32 or _bits(network.n_lanes - 1) + qbits + lbits > 62:
        return None
    target = max(network.n_lanes, 2 * per_env)
    qdrop = qbits
    while qdrop > 0 and network.n_lanes << (qbits - qdrop + 1) <= target:
        qdrop -= 1
    n_on = network.lane_centres_s.shape[1]
    centre_at = (_centre_thresholds(network.segment_length_m, network.lane_offset_m, clear_m,
                                    n_on) if candidate else np.empty(0))
    return n_col, qbits, lbits, qdrop, centre_at


def build_view_fast(
    network: GridNetwork, window_m: float, clear_m: float, active: np.ndarray,
    lane: np.ndarray, s: np.ndarray, q_scale: float, candidate: bool,
    workspace: ViewWorkspace | None = None,
) -> VirtualLaneView | None:
    """The compiled view, or None where the reference path must run (see the module doc).

    With ``workspace`` the view's arrays are slices of its buffers (see
    :class:`ViewWorkspace` for how long they stay valid); without, they are fresh arrays.
    """
    from mivecc_env.sim.virtual_lane import VirtualLaneView

    if not HAVE_NUMBA:
        return None
    bsz, cap = active.shape
    key = (network, float(window_m), float(clear_m), bsz, cap, float(q_scale), bool(candidate))
    last = None if workspace is None else workspace.layout_key
    if last is not None and last[0] is network and last[1:] == key[1:]:
        layout = workspace.layout
    else:
        layout = _layout(*key)
        if workspace is not None:
            workspace.layout_key, workspace.layout = key, layout
    if layout is None:
        return None
    n_col, qbits, lbits, qdrop, centre_at = layout
    n_lanes = network.n_lanes
    n_slots = bsz * cap
    n_buckets = n_lanes << (qbits - qdrop)
    if workspace is None:
        bufs = _allocate(n_slots, n_slots * (1 + n_col))
        scratch = _scratch(cap * (1 + n_col), n_buckets, n_lanes)
    else:
        bufs = workspace.take(n_slots, n_slots * (1 + n_col))
        scratch = workspace.take_scratch(cap * (1 + n_col), n_buckets, n_lanes)
    n, size, ok = _build(
        active, lane, s, network.lane_cp_s, network.lane_cp_other_lane,
        network.lane_cp_other_s, float(window_m), float(clear_m), centre_at, bool(candidate),
        n_lanes, float(q_scale), qbits, lbits, qdrop, *scratch, bufs["vi"], bufs["vf"],
        bufs["pi"], bufs["pf"], bufs["pb"],
    )
    if not ok:
        return None
    # positional: _FIELDS is in the dataclass's field order
    return VirtualLaneView(*[row[:size] if per_point else row[:n]
                             for row, per_point in bufs["fields"]])
