"""Versioned entry point of the vehicle-agent view (every vehicle in a control area an agent).

Example:
    >>> from mivecc_env import mivecc_vehicles_v0
    >>> env = mivecc_vehicles_v0.parallel_env(rows=1, cols=1, density=900, max_steps=300)
    >>> obs, infos = env.reset(seed=0)
    >>> while env.agents:
    ...     actions = {a: env.action_space(a).sample() for a in env.agents}
    ...     obs, rewards, terminated, truncated, infos = env.step(actions)

``env()`` is the AEC version (agents act in turn; vehicles that joined during a step act from
the next cycle on).
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils import wrappers
from pettingzoo.utils.env import AECEnv

from mivecc_env.aec import checked_aec
from mivecc_env.vehicle_env import MiVeCCVehiclesParallelEnv


def parallel_env(**kwargs: Any) -> MiVeCCVehiclesParallelEnv:
    """The vehicle-agent ParallelEnv (:mod:`mivecc_env.vehicle_env`): ``k``,
    ``collision_penalty``, ``safety_weight`` and config fields as keywords."""
    return MiVeCCVehiclesParallelEnv(**kwargs)


def raw_env(**kwargs: Any) -> AECEnv:
    """The AEC version of :func:`parallel_env`, as PettingZoo's ``parallel_to_aec`` builds it,
    each action checked when it is given."""
    return checked_aec(parallel_env(**kwargs))


def env(**kwargs: Any) -> AECEnv:
    """The AEC environment with PettingZoo's standard safety wrappers."""
    return wrappers.OrderEnforcingWrapper(raw_env(**kwargs))
