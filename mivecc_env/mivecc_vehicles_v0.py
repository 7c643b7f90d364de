"""Versioned entry point of the vehicle-agent view (every vehicle in a control area an agent).

Example:
    >>> from mivecc_env import mivecc_vehicles_v0
    >>> env = mivecc_vehicles_v0.parallel_env(rows=1, cols=1, density=900, max_steps=300)
    >>> obs, infos = env.reset(seed=0)
    >>> while env.agents:
    ...     actions = {a: env.action_space(a).sample() for a in env.agents}
    ...     obs, rewards, terminated, truncated, infos = env.step(actions)
"""

from __future__ import annotations

from typing import Any

from mivecc_env.vehicle_env import MiVeCCVehiclesParallelEnv


def parallel_env(**kwargs: Any) -> MiVeCCVehiclesParallelEnv:
    """The vehicle-agent ParallelEnv (:mod:`mivecc_env.vehicle_env`): ``k``,
    ``collision_penalty``, ``safety_weight`` and config fields as keywords."""
    return MiVeCCVehiclesParallelEnv(**kwargs)
