"""Decision-vehicle selection and K x K x 3 state graphs of the edge and cloud nodes.

A state graph has shape ``(K, K, 3)`` (rows, columns, channels position/velocity/acceleration).
Column ``j`` belongs to decision vehicle ``j``: row 0 is the vehicle itself, rows ``1..K-1`` its
``K - 1`` nearest reference vehicles on its virtual lane, nearest first. Fewer vehicles than K
leave zero padding; ``mask`` marks the real columns.

Features (all scaled to ``[-1, 1]``):

* position: row 0, the signed distance from the next conflict point ahead (the lane end once
  past the last one), negative before it; other rows, the reference's position minus the
  decision vehicle's on the virtual lane. Divided by the node's position scale
  (edge: ``2 * control_radius_m``, cloud: the longest lane) and clipped to ``[-1, 1]``.
* velocity: ``2 (v - v_floor) / (v_max - v_floor) - 1``.
* acceleration: ``a / accel_scale_mps2(config)``: ``a_max`` under unsignalized control, and
  ``max(a_max, idm_max_decel_mps2)`` under signals, whose emergency braking (9 m/s^2 by default)
  exceeds ``a_max``. So every channel stays in ``[-1, 1]``, the observation box; velocity and
  acceleration are also clipped to it, a guard that no current control mode reaches.

Edge node of intersection ``i``: decision vehicles are the (up to) K vehicles with the lowest
safety value inside its control area; references come from the part of the virtual lane inside
that area. Cloud node: the K vehicles with the highest density indicator among its population
(:func:`cloud_population`: by default the vehicles that still have a conflict point ahead);
references from the whole virtual lane.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import graph_kernel
from mivecc_env.sim.network import GridNetwork
from mivecc_env.sim.virtual_lane import VirtualLaneView, density_indicator

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: ``build_graphs(area_centre_s=_CENTRE_OF_NODE)``: the centres of the decisions' areas
#: (intersection ``node % n_nodes``) are looked up on their lanes (in the kernel).
_CENTRE_OF_NODE = np.zeros(0)


@dataclass(frozen=True)
class StateGraphs:
    """State graphs of one node kind for a batch of environments.

    Attributes:
        obs: (B, n_nodes, K, K, 3) float32 features.
        mask: (B, n_nodes, K) float32, 1 for a real decision vehicle.
        slot: (B, n_nodes, K) flat vehicle slot (``env * capacity + slot``) of each column,
            -1 for padding.
        view_index: (B, n_nodes, K) index of each column's vehicle in the view, -1 padding.
    """

    obs: NDArray[np.float32]
    mask: NDArray[np.float32]
    slot: IntArray
    view_index: IntArray


def accel_scale_mps2(config: MiVeCCConfig) -> float:
    """Largest acceleration magnitude [m/s^2] of the control mode (scale of the accel channel)."""
    if config.control == "signalized":
        return max(config.a_max_mps2, config.idm_max_decel_mps2)
    return config.a_max_mps2


def _unit_clip(x: FloatArray) -> FloatArray:
    """Clip to [-1, 1] (cheaper than ``np.clip`` on small arrays)."""
    return np.minimum(np.maximum(x, -1.0), 1.0)


def _rank_in_groups(sorted_groups: IntArray) -> IntArray:
    """Position of each element within its run of equal, sorted group ids."""
    if sorted_groups.size == 0:
        return sorted_groups.copy()
    first = np.searchsorted(sorted_groups, sorted_groups, side="left")
    return np.arange(sorted_groups.size) - first


def select_edge_decisions(
    network: GridNetwork, view: VirtualLaneView, sv: FloatArray, k: int, config: MiVeCCConfig,
    area: IntArray | None = None,
) -> tuple[IntArray, IntArray, IntArray]:
    """Up to ``k`` lowest-SV vehicles per (environment, control area).

    Args:
        area: (n,) control area of each view vehicle if the caller has it already
            (``network.control_area(view.lane, view.s)``).

    Returns:
        (view index, node = env * n_intersections + intersection, column) of each decision.
    """
    if area is None:
        area = network.control_area(view.lane, view.s)
    if graph_kernel.HAVE_NUMBA:  # groups env * n_intersections + area, top-k: one call
        return graph_kernel.select_nodes(view.env, area, network.n_intersections, sv, k)
    inside = np.flatnonzero(area >= 0)
    node = view.env[inside] * network.n_intersections + area[inside]
    # Exact two-key sort (node, then SV; ties keep view order): a float composite key such as
    # ``node * span + sv`` rounds SV differences away once ``node`` is large.
    order = np.lexsort((sv[inside], node))
    chosen, node = inside[order], node[order]
    column = _rank_in_groups(node)
    keep = column < k
    return chosen[keep], node[keep], column[keep]


def population_limit_s(network: GridNetwork, population: str) -> FloatArray | None:
    """(n_lanes,) position [m] on each lane before which a vehicle is in the cloud's pick
    ``population`` (:func:`cloud_population`), or ``None`` for ``"network"`` (everyone).

    Depends only on the network: callers that observe every step compute it once.
    """
    if population == "network":
        return None
    if population == "conflict_ahead":
        marks = network.lane_cp_s
    elif population == "before_last_centre":
        marks = network.lane_centres_s
    else:
        raise ValueError(
            "population: must be 'conflict_ahead', 'before_last_centre' or 'network', "
            f"got {population!r}"
        )
    return np.where(np.isfinite(marks), marks, -np.inf).max(axis=1)


def cloud_population(
    network: GridNetwork, view: VirtualLaneView, population: str,
    limit_s: FloatArray | None = None,
) -> NDArray[np.bool_]:
    """(n,) True for the view vehicles the cloud may pick (config ``cloud_pick_population``).

    * ``"conflict_ahead"``: a conflict point of its lane is still ahead
      (``s <`` the lane's last conflict point, ``lane_offset_m`` past its last centre);
    * ``"before_last_centre"``: before the last intersection centre of its lane (the released
      code); it differs from ``conflict_ahead`` by the ``lane_offset_m`` (5 m) between the last
      centre and the last conflict point, where a vehicle still crosses one lane;
    * ``"network"``: every vehicle (on the exit links nothing conflicts any more).

    ``limit_s``: ``population_limit_s(network, population)`` if the caller has it already.
    """
    if limit_s is None:
        limit_s = population_limit_s(network, population)
    if limit_s is None:
        return np.ones(view.n_vehicles, dtype=bool)
    return view.s < limit_s[view.lane]


def select_cloud_decisions(
    view: VirtualLaneView, di: FloatArray, k: int, di_max: float,
    eligible: NDArray[np.bool_] | None = None,
) -> tuple[IntArray, IntArray, IntArray]:
    """Up to ``k`` highest-DI vehicles per environment: (view index, env, column).

    Args:
        eligible: (n,) the vehicles that may be picked (:func:`cloud_population`); all if None.
    """
    if graph_kernel.HAVE_NUMBA:  # key -min(di, di_max), groups the environments: one call
        return graph_kernel.select_capped_desc(view.env, eligible, di, di_max, k)
    if eligible is not None:
        # Select among the eligible vehicles only (the selection reads ``view.env``).
        cand = np.flatnonzero(eligible)
        sub = dataclasses.replace(view, env=view.env[cand])
        chosen, env, column = select_cloud_decisions(sub, di[cand], k, di_max)
        return cand[chosen], env, column
    # Exact two-key sort (env, then DI descending; ties keep view order), see above.
    order = np.lexsort((-np.minimum(di, di_max), view.env))
    env = view.env[order]
    column = _rank_in_groups(env)
    keep = column < k
    return order[keep], env[keep], column[keep]


def build_graphs(
    network: GridNetwork,
    view: VirtualLaneView,
    velocity: FloatArray,
    accel: FloatArray,
    decision: IntArray,
    node: IntArray,
    column: IntArray,
    n_nodes: int,
    batch: int,
    k: int,
    position_scale_m: float,
    config: MiVeCCConfig,
    area_centre_s: FloatArray | None = None,
    area_radius_m: float = np.inf,
    use_kernel: bool | None = None,
    references: IntArray | None = None,
) -> StateGraphs:
    """Fill the K x K x 3 graphs of the given decisions.

    Args:
        velocity / accel: (n,) per view vehicle [m/s], [m/s^2].
        decision / node / column: selections from ``select_*_decisions`` (node is
            ``env * n_nodes + node_in_env``).
        area_centre_s: (len(decision),) centre of each decision's area on its lane [m];
            references outside ``area_radius_m`` of it are ignored (edge nodes).
            ``_CENTRE_OF_NODE``: the area is intersection ``node % n_nodes``, its centre
            looked up on the decision's lane (as :func:`edge_graphs` needs).
        use_kernel: fill the graphs with the compiled kernel
            (:func:`mivecc_env.sim.graph_kernel.build`, bit-identical) or the numpy path;
            default: the kernel when numba is available.
        references: optional (len(decision), K-1) int64 output, filled with the view index of
            each decision's reference rows, nearest first, -1 for padding.
    """
    shape = (batch, n_nodes, k)
    v_lo = config.velocity_floor_mps
    inv_scale = 1.0 / position_scale_m
    v_mul = 2.0 / (config.v_max_mps - v_lo)
    a_mul = 1.0 / accel_scale_mps2(config)
    if use_kernel is None:
        use_kernel = graph_kernel.HAVE_NUMBA
    if use_kernel and decision.size:  # the kernel writes every output element
        obs = np.empty((*shape, k, 3), dtype=np.float32)  # (env, node, row, column, channel)
        mask = np.empty(shape, dtype=np.float32)
        slot = np.empty(shape, dtype=np.int64)
        view_index = np.empty(shape, dtype=np.int64)
        centre = area_centre_s
        if centre is _CENTRE_OF_NODE:
            centre = (n_nodes, network.lane_intersections, network.lane_centres_s)
        graph_kernel.build(obs.reshape(-1, 3), mask.reshape(-1), slot.reshape(-1),
                           view_index.reshape(-1), k, decision, node, column, view, velocity,
                           accel, v_lo, v_mul, a_mul, network.lane_cp_s, network.lane_length,
                           centre, area_radius_m, inv_scale,
                           None if references is None else references.reshape(-1))
        return StateGraphs(obs, mask, slot, view_index)
    obs = np.zeros((*shape, k, 3), dtype=np.float32)
    mask = np.zeros(shape, dtype=np.float32)
    slot = np.full(shape, -1, dtype=np.int64)
    view_index = np.full(shape, -1, dtype=np.int64)

    def finish() -> StateGraphs:
        return StateGraphs(obs, mask, slot, view_index)

    if references is not None:
        references[:] = -1
    if decision.size == 0:
        return finish()
    if area_centre_s is _CENTRE_OF_NODE:
        lane = view.lane[decision]
        which = np.argmax(network.lane_intersections[lane] == (node % n_nodes)[:, None], axis=1)
        area_centre_s = network.lane_centres_s[lane, which]

    s_d = view.s[decision]
    to_stop = s_d - network.next_stop_s(view.lane[decision], s_d)
    n_veh = velocity.size
    # Channels velocity and acceleration of every view vehicle, plus a zero row for padding.
    va = np.zeros((n_veh + 1, 2), dtype=np.float32)
    va[:n_veh, 0] = _unit_clip((velocity - v_lo) * v_mul - 1.0)
    va[:n_veh, 1] = _unit_clip(accel * a_mul)
    # obs viewed as (node * K * K, 3): cell (node, row, column) is row (node*K + row)*K + column
    cells = obs.reshape(-1, 3)
    head_cell = node * (k * k) + column
    cells[head_cell, 0] = _unit_clip(to_stop * inv_scale)
    cells[head_cell, 1:] = va[decision]

    ref, rel = nearest_references(view, decision, k - 1, area_centre_s, area_radius_m)
    n_ref = ref.shape[1]
    if references is not None:
        references[:, :n_ref] = ref
    real = ref >= 0
    ref_vehicle = np.where(real, ref, n_veh)
    block = np.empty((decision.size, n_ref, 3), dtype=np.float32)
    block[..., 0] = np.where(real, _unit_clip(rel * inv_scale), 0.0)
    block[..., 1:] = va[ref_vehicle]
    ref_cell = head_cell[:, None] + np.arange(1, n_ref + 1) * k
    cells[ref_cell] = block

    return _finish_masks(finish(), node, column, view, decision)


def nearest_references(
    view: VirtualLaneView, decision: IntArray, n_ref: int,
    area_centre_s: FloatArray | None = None, area_radius_m: float = np.inf,
) -> tuple[IntArray, FloatArray]:
    """The ``n_ref`` nearest reference vehicles of each decision on its virtual lane.

    The graphs' rule (:func:`build_graphs`, :func:`reference_order`): candidates are up to
    ``n_ref`` points on either side of the decision's own point on the sorted virtual lane,
    clipped to the lane's run (the decision's own point is not one), and, with
    ``area_centre_s``, only those within ``area_radius_m`` of that centre on the lane.

    Args:
        decision: (D,) view index of each decision vehicle.
        area_centre_s: (D,) centre of each decision's area on its lane [m], or None.

    Returns:
        (D, m) view index of each reference, nearest first, -1 where fewer exist, and
        (D, m) its position minus the decision's on the virtual lane [m] (0 there), with
        ``m = min(n_ref, the widest candidate window)``.
    """
    s_d = view.s[decision]
    p = view.own_point[decision]
    lo = np.maximum(view.point_run_start[p], p - n_ref)
    hi = np.minimum(view.point_run_end[p], p + n_ref + 1)  # exclusive
    width = int((hi - lo).max()) if decision.size else 0
    cand = lo[:, None] + np.arange(width)
    valid = (cand < hi[:, None]) & (cand != p[:, None])
    np.minimum(cand, max(view.point_pos.size - 1, 0), out=cand)
    pos = view.point_pos[cand]
    if area_centre_s is not None:
        valid &= np.abs(pos - area_centre_s[:, None]) <= area_radius_m
    rel = pos - s_d[:, None]
    nearest = reference_order(cand, p, valid, np.abs(rel))[:, :n_ref]
    pick = nearest + (np.arange(decision.size) * width)[:, None]  # flat index into (D, width)
    real = valid.ravel()[pick]
    ref = np.where(real, view.point_vehicle[cand.ravel()[pick]], -1)
    return ref, np.where(real, rel.ravel()[pick], 0.0)


def reference_order(cand: IntArray, point: IntArray, valid: NDArray[np.bool_],
                    dist: FloatArray) -> IntArray:
    """(D, W) order of each decision's reference candidates, nearest first (invalid ones last).

    The rule (the compiled kernel's, :func:`mivecc_env.sim.graph_kernel.build`): each side of
    the decision's own point is taken in the view's point order, nearest first (behind:
    decreasing point index, a run of equal distances in increasing index; ahead: increasing
    index), and the two sides are merged by distance, a tie going to the point behind. The view
    sorts points by position quantised to 0.1 mm (:mod:`~mivecc_env.sim.virtual_lane`), so
    within 0.1 mm a side may be out of exact distance order and its order stands. A merge of
    two sequences equals a stable sort by each side's running maximum of the distance (the
    side behind first on a tie), which is what this computes.

    Args:
        cand: (D, W) point index of each candidate, increasing along a row.
        point: (D,) the decision's own point.
        valid: (D, W) the candidates that may be references.
        dist: (D, W) their distance to the decision [m].
    """
    d, w = cand.shape
    cols = np.arange(w)
    behind = valid & (cand < point[:, None])
    ahead = valid & (cand > point[:, None])
    running_ahead = np.maximum.accumulate(np.where(ahead, dist, -np.inf), axis=1)
    flip_dist = np.where(behind, dist, -np.inf)[:, ::-1]  # behind, nearest first
    running_behind = np.maximum.accumulate(flip_dist, axis=1)[:, ::-1]
    key = np.where(behind, running_behind, np.where(ahead, running_ahead, np.inf))
    # inside the side behind: runs of equal distance (consecutive valid points) nearest first,
    # each run in increasing point index
    flip_valid = behind[:, ::-1]
    last = np.maximum.accumulate(np.where(flip_valid, cols, -1), axis=1)
    prev = np.concatenate([np.full((d, 1), -1), last[:, :-1]], axis=1)
    prev_dist = np.take_along_axis(flip_dist, np.maximum(prev, 0), axis=1)
    run = np.cumsum(flip_valid & ((prev < 0) | (flip_dist != prev_dist)), axis=1)[:, ::-1]
    second = np.where(behind, run * w + cols, w * w + cols)
    return np.lexsort((second, key), axis=1)


def _finish_masks(graphs: StateGraphs, node: IntArray, column: IntArray, view: VirtualLaneView,
                  decision: IntArray) -> StateGraphs:
    """Mark each decision's column in ``mask``, ``slot`` and ``view_index``."""
    n_nodes_k = graphs.mask.shape[-1]
    flat = node * n_nodes_k + column
    graphs.mask.reshape(-1)[flat] = 1.0
    graphs.slot.reshape(-1)[flat] = view.vehicle[decision]
    graphs.view_index.reshape(-1)[flat] = decision
    return graphs


def edge_graphs(
    network: GridNetwork, view: VirtualLaneView, sv: FloatArray, velocity: FloatArray,
    accel: FloatArray, batch: int, config: MiVeCCConfig, area: IntArray | None = None,
) -> StateGraphs:
    """Edge-node graphs, (B, n_intersections, K_edge, K_edge, 3) (``area``: see
    :func:`select_edge_decisions`)."""
    k = config.k_edge
    decision, node, column = select_edge_decisions(network, view, sv, k, config, area)
    if graph_kernel.HAVE_NUMBA and decision.size:  # the kernel looks the centres up itself
        return build_graphs(
            network, view, velocity, accel, decision, node, column, network.n_intersections,
            batch, k, 2.0 * config.control_radius_m, config, _CENTRE_OF_NODE,
            config.control_radius_m,
        )
    area = node % network.n_intersections
    lane = view.lane[decision]
    if graph_kernel.HAVE_NUMBA:
        centre = graph_kernel.area_centres(lane, area, network.lane_intersections,
                                           network.lane_centres_s)
    else:
        which = np.argmax(network.lane_intersections[lane] == area[:, None], axis=1)
        centre = network.lane_centres_s[lane, which]
    return build_graphs(
        network, view, velocity, accel, decision, node, column, network.n_intersections,
        batch, k, 2.0 * config.control_radius_m, config, centre, config.control_radius_m,
    )


def cloud_graphs(
    network: GridNetwork, view: VirtualLaneView, di: FloatArray | None, velocity: FloatArray,
    accel: FloatArray, batch: int, config: MiVeCCConfig,
    eligible: NDArray[np.bool_] | None = None,
) -> StateGraphs:
    """Cloud-node graphs, (B, G, K_cloud, K_cloud, 3): G = 1, the network's K highest-DI
    vehicles; or, with ``config.cloud_graphs == "per_lane"``, G = ``network.n_lanes``, graph
    ``l`` holding the K highest-DI vehicles of through lane ``l`` (the paper's Algorithm 1).

    Args:
        di: (n,) density indicator of the view vehicles, or ``None``: the view's
            ``density_indicator(view, config.di_n)`` (computed inside the compiled selection,
            only for the eligible vehicles, when numba is available).
        eligible: (n,) vehicles the cloud may pick; default
            ``cloud_population(network, view, config.cloud_pick_population)``.
    """
    k = config.k_cloud
    longest = float(network.lane_length.max())
    if eligible is None:
        eligible = cloud_population(network, view, config.cloud_pick_population)
    n_graphs = network.n_lanes if config.cloud_graphs == "per_lane" else 1
    # the selection groups by view.env: one group (graph) per environment, or per lane
    group_view = view if n_graphs == 1 else dataclasses.replace(
        view, env=view.env * n_graphs + view.lane)
    if di is None and graph_kernel.HAVE_NUMBA:
        decision, node, column = graph_kernel.select_cloud_di(
            group_view.env, eligible, view.own_point, view.point_run_start,
            view.point_run_end, view.point_pos, config.di_n, longest, k)
    else:
        if di is None:
            di = density_indicator(view, config.di_n)
        decision, node, column = select_cloud_decisions(group_view, di, k, longest, eligible)
    return build_graphs(
        network, view, velocity, accel, decision, node, column, n_graphs, batch, k, longest,
        config,
    )
