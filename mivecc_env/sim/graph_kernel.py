"""Compiled (numba) fill of the state graphs' reference rows, identical to the numpy path.

For each decision vehicle the numpy path of :func:`mivecc_env.sim.state_graph.build_graphs`
takes the candidate points on either side of its own point on the sorted virtual lane, drops
the invalid ones (outside the lane's run or the node's area), and stable-sorts the rest by
distance (ties: lower point index first) to keep the K-1 nearest. Both halves are already
sorted by distance, so this kernel merges them with two pointers instead: behind the vehicle a
run of equal distances is emitted in increasing point index (the stable sort's tie order), and
a tie between the two halves goes to the point behind (the lower index). The features are the
same float operations in the same order, so the result is bit-identical (tested).
"""

from __future__ import annotations

import numpy as np

from mivecc_env.sim._numba import HAVE_NUMBA, njit

__all__ = ["HAVE_NUMBA", "fill_references"]


@njit
def _fill(cells, head_cell, k, own_point, s_d, lo, hi, point_pos, point_vehicle, va,
          centre, radius, use_area, inv_scale):  # pragma: no cover - compiled
    n_dec = own_point.shape[0]
    n_veh = va.shape[0] - 1
    b_idx = np.empty(k, np.int64)
    b_dist = np.empty(k, np.float64)
    b_rel = np.empty(k, np.float64)
    a_idx = np.empty(k, np.int64)
    a_dist = np.empty(k, np.float64)
    a_rel = np.empty(k, np.float64)
    for i in range(n_dec):
        p = own_point[i]
        s = s_d[i]
        # valid candidates behind (nearest first) and ahead (nearest first)
        nb = 0
        for q in range(p - 1, lo[i] - 1, -1):
            pos = point_pos[q]
            if use_area and not (abs(pos - centre[i]) <= radius):
                continue
            rel = pos - s
            b_idx[nb] = q
            b_rel[nb] = rel
            b_dist[nb] = abs(rel)
            nb += 1
        na = 0
        for q in range(p + 1, hi[i]):
            pos = point_pos[q]
            if use_area and not (abs(pos - centre[i]) <= radius):
                continue
            rel = pos - s
            a_idx[na] = q
            a_rel[na] = rel
            a_dist[na] = abs(rel)
            na += 1
        ib = 0
        ia = 0
        row = 1
        while row < k and (ib < nb or ia < na):
            if ib < nb and (ia >= na or b_dist[ib] <= a_dist[ia]):
                # a run of equal distances behind: lower point index (farther in the list) first
                end = ib
                while end + 1 < nb and b_dist[end + 1] == b_dist[ib]:
                    end += 1
                j = end
                while j >= ib and row < k:
                    _write(cells, head_cell[i] + row * k, b_rel[j], point_vehicle[b_idx[j]],
                           va, inv_scale)
                    row += 1
                    j -= 1
                ib = end + 1
            else:
                _write(cells, head_cell[i] + row * k, a_rel[ia], point_vehicle[a_idx[ia]],
                       va, inv_scale)
                row += 1
                ia += 1
    return n_veh


@njit
def _write(cells, cell, rel, vehicle, va, inv_scale):  # pragma: no cover - compiled
    x = rel * inv_scale
    x = min(max(x, -1.0), 1.0)
    cells[cell, 0] = np.float32(x)
    cells[cell, 1] = va[vehicle, 0]
    cells[cell, 2] = va[vehicle, 1]


def fill_references(
    cells: np.ndarray, head_cell: np.ndarray, k: int, own_point: np.ndarray, s_d: np.ndarray,
    lo: np.ndarray, hi: np.ndarray, point_pos: np.ndarray, point_vehicle: np.ndarray,
    va: np.ndarray, centre: np.ndarray | None, radius: float, inv_scale: float,
) -> None:
    """Write rows ``1..K-1`` of every decision's column into ``cells`` ((N*K*K, 3) float32).

    Args:
        head_cell: (D,) cell index of each decision's row 0.
        own_point / s_d / lo / hi: (D,) own point, position [m] and candidate index range
            ``[lo, hi)`` of each decision.
        va: (n+1, 2) float32 velocity/acceleration channels per view vehicle (last row 0).
        centre / radius: area filter (``None``: no filter).
    """
    use_area = centre is not None
    c = centre if use_area else np.zeros(0)
    _fill(cells, head_cell, k, own_point, s_d, lo, hi, point_pos, point_vehicle, va, c,
          float(radius), use_area, float(inv_scale))


@njit
def _select(group, key, n_groups, k):  # pragma: no cover - compiled
    n = group.shape[0]
    count = np.zeros(n_groups + 1, np.int64)
    for i in range(n):
        if group[i] >= 0:
            count[group[i] + 1] += 1
    for g in range(n_groups):
        count[g + 1] += count[g]
    start = count.copy()
    members = np.empty(count[n_groups], np.int64)
    for i in range(n):  # counting sort by group: index order within a group
        g = group[i]
        if g >= 0:
            members[start[g]] = i
            start[g] += 1
    out_idx = np.empty(count[n_groups], np.int64)
    out_group = np.empty(count[n_groups], np.int64)
    out_col = np.empty(count[n_groups], np.int64)
    m = 0
    for g in range(n_groups):
        lo, hi = count[g], count[g + 1]
        if hi == lo:
            continue
        idx = members[lo:hi]
        order = np.argsort(key[idx], kind="mergesort")  # stable: ties keep index order
        for c in range(min(k, hi - lo)):
            out_idx[m] = idx[order[c]]
            out_group[m] = g
            out_col[m] = c
            m += 1
    return out_idx[:m], out_group[:m], out_col[:m]


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
    return _select(group, key, n_groups, k)
