"""Compiled per-node sums of the reward terms (identical to the ``np.bincount`` reference).

``np.bincount(node, weights)`` adds the weights of each bin one by one in input order, so a
loop over the vehicles in view order gives the same float sums bit for bit; the reference stays
in :meth:`mivecc_env.batched.BatchedMiVeCCEnv._reward_terms` (used without numba and compared
in ``tests/env/test_reward_kernel.py``).
"""

from __future__ import annotations

import numpy as np

from mivecc_env.sim._numba import HAVE_NUMBA, njit

__all__ = ["HAVE_NUMBA", "node_sums"]


@njit
def _node_sums(env, area, eligible, velocity, v_ref, batch, n_nodes):  # pragma: no cover
    count = np.zeros(batch * n_nodes, np.int64)
    vel_sum = np.zeros(batch * n_nodes, np.float64)
    env_count = np.zeros(batch, np.int64)
    env_sum = np.zeros(batch, np.float64)
    for i in range(env.shape[0]):
        dv = velocity[i] - v_ref
        if area[i] >= 0:
            node = env[i] * n_nodes + area[i]
            count[node] += 1
            vel_sum[node] += dv
        if eligible[i]:
            env_count[env[i]] += 1
            env_sum[env[i]] += dv
    return count, vel_sum, env_count, env_sum


def node_sums(
    env: np.ndarray, area: np.ndarray, eligible: np.ndarray, velocity: np.ndarray,
    v_ref: float, batch: int, n_nodes: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vehicle counts and sums of ``velocity - v_ref`` per edge node and per environment.

    Args:
        env / area: (n,) environment and control area (-1 outside) of each view vehicle.
        eligible: (n,) bool, the cloud's population.
        velocity: (n,) [m/s]; ``v_ref``: the reward's reference velocity [m/s].

    Returns:
        ``(count, vel_sum)`` per node ``env * n_nodes + area``, (B * n_nodes,), and
        ``(env_count, env_sum)`` of the eligible vehicles per environment, (B,).
    """
    return _node_sums(env, area, eligible, velocity, float(v_ref), int(batch), int(n_nodes))


@njit
def _terms(edge_out, cloud_out, env, area, eligible, velocity, v_ref, n_nodes, hit_env,
           hit_area, hit_vehicles, neg_penalty, sv_sum, view_index, sv_weight,
           has_sv):  # pragma: no cover - compiled; compared with the numpy reference
    count, vel_sum, env_count, env_sum = _node_sums(env, area, eligible, velocity, v_ref,
                                                    cloud_out.shape[1], n_nodes)
    hits = np.zeros(count.shape[0], np.int64)
    for i in range(hit_env.shape[0]):
        if hit_area[i] >= 0:
            hits[hit_env[i] * n_nodes + hit_area[i]] += 1
    k = view_index.shape[1]
    for g in range(count.shape[0]):
        sv = 0.0
        if has_sv:
            n_dec = 0
            for j in range(k):
                if view_index[g, j] >= 0:
                    n_dec += 1
            sv = sv_weight * (sv_sum[g] / max(n_dec, 1))
        vel = vel_sum[g] / max(count[g], 1)
        col = neg_penalty * hits[g]
        edge_out[0, g] = sv
        edge_out[1, g] = vel
        edge_out[2, g] = col
        edge_out[3, g] = sv + vel + col
    for e in range(cloud_out.shape[1]):
        vel = env_sum[e] / max(env_count[e], 1)
        col = neg_penalty * float(hit_vehicles[e])
        cloud_out[0, e] = 0.0
        cloud_out[1, e] = vel
        cloud_out[2, e] = col
        cloud_out[3, e] = 0.0 + vel + col


def terms(
    env: np.ndarray, area: np.ndarray, eligible: np.ndarray, velocity: np.ndarray,
    v_ref: float, batch: int, n_nodes: int, hit_env: np.ndarray, hit_area: np.ndarray,
    hit_vehicles: np.ndarray, collision_penalty: float, sv_sum: np.ndarray | None,
    view_index: np.ndarray | None, sv_weight: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The reward terms and totals of every edge node and environment in one call.

    The values of ``BatchedMiVeCCEnv._reward_terms`` (default ``edge_reward_scope``) and of
    their sums, with the same IEEE operations in the same order (compared bit for bit in
    ``tests/env/test_reward_kernel.py``).

    Args:
        env / area / eligible / velocity / v_ref: as for :func:`node_sums`.
        hit_env / hit_area: (k,) environment and control area (-1 outside) of each vehicle
            removed by collision in the step; ``hit_vehicles``: (B,) their number per env.
        collision_penalty: the penalty per removed vehicle.
        sv_sum: (B * n_nodes,) sum of the SVs of each node's decision vehicles, and
            ``view_index``: (B * n_nodes, K) the decisions' view indices (-1 padding); both
            ``None`` when the edge graphs are not built (``reward_sv`` is then 0).
        sv_weight: ``reward_sv_weight``.

    Returns:
        ``(edge, cloud)``: (4, B * n_nodes) and (4, B) float64, rows ``reward_sv``,
        ``reward_velocity``, ``reward_collision`` and their sum (the reward).
    """
    has_sv = sv_sum is not None and view_index is not None
    if not has_sv:
        sv_sum = np.zeros(0)
        view_index = np.zeros((0, 1), np.int64)
    edge = np.empty((4, batch * n_nodes))
    cloud = np.empty((4, batch))
    _terms(edge, cloud, env, area, eligible, velocity, float(v_ref), int(n_nodes), hit_env,
           hit_area, hit_vehicles, -float(collision_penalty), sv_sum, view_index,
           float(sv_weight), has_sv)
    return edge, cloud
