"""Versioned entry point of the MiVeCC environment, following PettingZoo conventions.

Example:
    >>> from mivecc_env import mivecc_v0
    >>> env = mivecc_v0.parallel_env(rows=1, cols=1, density=900, max_steps=100)
    >>> observations, infos = env.reset(seed=0)
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils import wrappers
from pettingzoo.utils.env import AECEnv

from mivecc_env.aec import checked_aec
from mivecc_env.parallel_env import MiVeCCParallelEnv


def parallel_env(**overrides: Any) -> MiVeCCParallelEnv:
    """The ParallelEnv; keywords are config fields (``rows``, ``cols``, ``density``, ...)."""
    return MiVeCCParallelEnv(**overrides)


def raw_env(**overrides: Any) -> AECEnv:
    """The AEC version of :func:`parallel_env` (agents act in turn, one step per cycle), as
    PettingZoo's ``parallel_to_aec`` builds it, each action checked when it is given."""
    return checked_aec(parallel_env(**overrides))


def env(**overrides: Any) -> AECEnv:
    """The AEC environment with PettingZoo's standard safety wrappers."""
    aec = raw_env(**overrides)
    return wrappers.OrderEnforcingWrapper(aec)
