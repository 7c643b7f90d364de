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
            clear_m, seg, off, n_on, candidate, n_lanes, q_scale, qbits, ibits, vehicle, env,
            v_lane, v_s, group, pos, src, keys):  # pragma: no cover
    """Pass 1: vehicles, points and packed sort keys (see the module docstring).

    Writes into the given buffers (vehicle arrays at least as long as the slots, point arrays
    at least the slots times ``1 + n_col``) and returns (vehicles, points, keys in range).
    """
    bsz, cap = active.shape
    n_col = 2 if candidate else lane_cp_s.shape[1]
    n = 0
    for b in range(bsz):
        for k in range(cap):
            if active[b, k]:
                vehicle[n] = b * cap + k
                env[n] = b
                v_lane[n] = lane[b, k]
                v_s[n] = s[b, k]
                n += 1
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
    qmax = (np.int64(1) << qbits) - 1
    shift_g = qbits + ibits
    ok = True
    for j in range(size):
        q = np.int64((pos[j] + window_m) * q_scale)
        if q > qmax or q < 0:
            ok = False
        keys[j] = (group[j] << shift_g) | (q << ibits) | j
    return n, size, ok


@njit
def _neighbours(keys, pos, src, n, v_s, imask, shift_g, g_s, p_s, s_s, own, run_start, run_end,
                own_point, front, back, d_front, d_back, leader, follower):  # pragma: no cover
    """Pass 2: sorted point arrays, runs, front/back points and own-lane neighbours.

    Writes the first ``keys.size`` (points) or ``n`` (vehicles) entries of the given buffers.
    """
    size = keys.size
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
    return 0


def _bits(x: int) -> int:
    return max(1, int(x).bit_length())


#: (name, dtype, per-vehicle (False) or per-point (True)) of every buffer of one view.
_BUFFERS = (
    ("vehicle", np.int64, False), ("env", np.int64, False), ("lane", np.int64, False),
    ("s", np.float64, False), ("group", np.int64, True), ("pos", np.float64, True),
    ("src", np.int64, True), ("keys", np.int64, True), ("point_group", np.int64, True),
    ("point_pos", np.float64, True), ("point_vehicle", np.int64, True),
    ("point_own", np.bool_, True), ("point_run_start", np.int64, True),
    ("point_run_end", np.int64, True), ("own_point", np.int64, False),
    ("front_point", np.int64, False), ("back_point", np.int64, False),
    ("d_front", np.float64, False), ("d_back", np.float64, False),
    ("leader", np.int64, False), ("follower", np.int64, False),
)


def _allocate(n_vehicles: int, n_points: int) -> dict[str, np.ndarray]:
    return {name: np.empty(n_points if per_point else n_vehicles, dtype)
            for name, dtype, per_point in _BUFFERS}


class ViewWorkspace:
    """Reusable output buffers of :func:`build_view_fast`, owned by one caller.

    The compiled passes write into these buffers instead of returning fresh arrays (each
    array a numba kernel returns costs a Python-side boxing call). The view of a call is
    made of slices of one of two buffer sets used in turn, so the view returned by the
    previous call stays intact while the next one is built; the view two builds back is
    overwritten. Use it only where no view outlives the next build: the simulator's own view
    (``Simulator.view``, rebuilt by every ``step`` and ``reset_at``; the simulator copies the
    one array it keeps for the next step). Buffers grow (never shrink) to the largest batch
    seen.
    """

    def __init__(self) -> None:
        self._sets: list[dict[str, np.ndarray]] = [{}, {}]
        self._turn = 0
        #: arguments and result of the last ``_layout`` (the key layout of the batch shape)
        self.layout_key: tuple | None = None
        self.layout: tuple[int, int, int] | None = None

    def take(self, n_vehicles: int, n_points: int) -> dict[str, np.ndarray]:
        """The next buffer set, with room for ``n_vehicles`` vehicles and ``n_points``
        points."""
        self._turn ^= 1
        bufs = self._sets[self._turn]
        if not bufs or bufs["vehicle"].size < n_vehicles or bufs["keys"].size < n_points:
            bufs = _allocate(n_vehicles, n_points)
            self._sets[self._turn] = bufs
        return bufs


def _layout(
    network: GridNetwork, window_m: float, clear_m: float, bsz: int, cap: int, q_scale: float,
    candidate: bool,
) -> tuple[int, int, int] | None:
    """(conflict columns tested per vehicle, position bits, point-index bits) of the packed
    key, or None where the batch is too large for it."""
    n_groups = bsz * network.n_lanes
    if n_groups > 1 << 16:  # the reference sorts such batches with a float argsort
        return None
    n_col = 2 if candidate else network.lane_cp_s.shape[1]
    reach = float(network.lane_length.max()) + clear_m + window_m
    qbits = _bits(int(reach * q_scale * 1.001) + 2)
    ibits = _bits(bsz * cap * (1 + n_col))
    if qbits > 32 or _bits(n_groups - 1) + qbits + ibits > 63:
        return None
    return n_col, qbits, ibits


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
    n_col, qbits, ibits = layout
    n_lanes = network.n_lanes
    n_slots = bsz * cap
    if workspace is None:
        bufs = _allocate(n_slots, n_slots * (1 + n_col))
    else:
        bufs = workspace.take(n_slots, n_slots * (1 + n_col))
    n, size, ok = _points(
        active, lane, s, network.lane_cp_s, network.lane_cp_other_lane,
        network.lane_cp_other_s, float(window_m), float(clear_m),
        float(network.segment_length_m), float(network.lane_offset_m),
        int(network.lane_centres_s.shape[1]), bool(candidate), n_lanes, float(q_scale),
        qbits, ibits, bufs["vehicle"], bufs["env"], bufs["lane"], bufs["s"], bufs["group"],
        bufs["pos"], bufs["src"], bufs["keys"],
    )
    if not ok:
        return None
    keys = bufs["keys"][:size]
    keys.sort()
    imask = (1 << ibits) - 1
    out = {name: bufs[name][:size if per_point else n] for name, _dtype, per_point in _BUFFERS
           if name not in ("group", "pos", "src", "keys")}
    _neighbours(keys, bufs["pos"], bufs["src"], n, out["s"], imask, qbits + ibits,
                out["point_group"], out["point_pos"], out["point_vehicle"], out["point_own"],
                out["point_run_start"], out["point_run_end"], out["own_point"],
                out["front_point"], out["back_point"], out["d_front"], out["d_back"],
                out["leader"], out["follower"])
    return VirtualLaneView(**out)
