"""mivecc_env: the MiVeCC road-network simulator and its PettingZoo / Gymnasium environments.

* :mod:`mivecc_env.sim` -- the batched numpy simulator (no RL imports);
* :mod:`mivecc_env.mivecc_v0` -- ``parallel_env()`` / ``env()`` (PettingZoo);
* ``gymnasium.make("mivecc/MiVeCCEdge-v0")`` -- a single-agent view: the edge node of one
  intersection (registered on import of this package).
"""

from __future__ import annotations

from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.metrics import episode_summary, upper_bound_velocity_mps
from mivecc_env.parallel_env import CLOUD_AGENT, MiVeCCParallelEnv, edge_agent

__version__ = "0.1.0"
ENV_VERSION = "mivecc_v0"

__all__ = [
    "CLOUD_AGENT",
    "ENV_VERSION",
    "ConfigError",
    "MiVeCCConfig",
    "MiVeCCParallelEnv",
    "__version__",
    "edge_agent",
    "episode_summary",
    "register_gymnasium",
    "upper_bound_velocity_mps",
]


def register_gymnasium() -> None:
    """Register ``mivecc/MiVeCCEdge-v0`` with gymnasium (idempotent)."""
    import gymnasium

    if "mivecc/MiVeCCEdge-v0" not in gymnasium.registry:
        gymnasium.register(
            id="mivecc/MiVeCCEdge-v0",
            entry_point="mivecc_env.single_agent:MiVeCCEdgeEnv",
            max_episode_steps=None,
        )


register_gymnasium()
