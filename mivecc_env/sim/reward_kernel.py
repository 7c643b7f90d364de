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
