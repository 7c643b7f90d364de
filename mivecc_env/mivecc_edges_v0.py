"""Versioned entry point of the edge-only view (homogeneous edge agents, no ``cloud_0``).

Example (SuperSuit + Stable-Baselines3, no other glue):
    >>> import supersuit as ss
    >>> from mivecc_env import mivecc_edges_v0
    >>> env = mivecc_edges_v0.parallel_env(rows=2, cols=2, density=1500)
    >>> vec = ss.pettingzoo_env_to_vec_env_v1(env)
    >>> vec = ss.concat_vec_envs_v1(vec, 2, base_class="stable_baselines3")
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils import wrappers
from pettingzoo.utils.env import AECEnv

from mivecc_env.aec import checked_aec
from mivecc_env.edge_view import MiVeCCEdgesParallelEnv


def parallel_env(**overrides: Any) -> MiVeCCEdgesParallelEnv:
    """The edge-only ParallelEnv; keywords as for :func:`mivecc_env.mivecc_v0.parallel_env`."""
    return MiVeCCEdgesParallelEnv(**overrides)


def raw_env(**overrides: Any) -> AECEnv:
    """The AEC version of :func:`parallel_env`, each action checked when it is given
    (:mod:`mivecc_env.aec`)."""
    return checked_aec(parallel_env(**overrides))


def env(**overrides: Any) -> AECEnv:
    """The AEC environment with PettingZoo's standard safety wrappers."""
    return wrappers.OrderEnforcingWrapper(raw_env(**overrides))
