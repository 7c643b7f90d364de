"""mivecc_env: the MiVeCC road-network simulator and its PettingZoo / Gymnasium environments.

* :mod:`mivecc_env.sim` -- the batched numpy simulator (no RL imports);
* :mod:`mivecc_env.batched` -- :class:`BatchedMiVeCCEnv`, B environments as numpy arrays;
* :mod:`mivecc_env.mivecc_v0` -- ``parallel_env()`` / ``env()`` (PettingZoo);
* :mod:`mivecc_env.mivecc_edges_v0` -- the edge-only view (homogeneous agents, no ``cloud_0``);
* :mod:`mivecc_env.mivecc_vehicles_v0` -- the vehicles in the control areas as agents that come
  and go (CoMADDPG's view);
* ``pettingzoo.make("parallel" | "aec", "mivecc/mivecc-v0")`` (and ``mivecc/mivecc_edges-v0``,
  ``mivecc/mivecc_vehicles-v0``) where the installed PettingZoo has a registry (1.27+;
  registered on import of this package);
* ``gymnasium.make("mivecc/MiVeCCEdge-v0")`` -- a single-agent view: the edge node of one
  intersection (registered on import of this package).
"""

from __future__ import annotations

from mivecc_env.batched import BatchedMiVeCCEnv, BatchStep
from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.edge_view import MiVeCCEdgesParallelEnv
from mivecc_env.metrics import episode_summary, upper_bound_velocity_mps
from mivecc_env.parallel_env import CLOUD_AGENT, MiVeCCParallelEnv, edge_agent

__version__ = "0.1.0"
ENV_VERSION = "mivecc_v0"

__all__ = [
    "CLOUD_AGENT",
    "ENV_VERSION",
    "BatchStep",
    "BatchedMiVeCCEnv",
    "ConfigError",
    "MiVeCCConfig",
    "MiVeCCEdgesParallelEnv",
    "MiVeCCParallelEnv",
    "__version__",
    "edge_agent",
    "episode_summary",
    "register_gymnasium",
    "register_pettingzoo",
    "upper_bound_velocity_mps",
]


def register_gymnasium() -> None:
    """Register ``mivecc/MiVeCCEdge-v0`` with gymnasium (idempotent)."""
    import gymnasium

    if "mivecc/MiVeCCEdge-v0" not in gymnasium.registry:
        gymnasium.register(
            id="mivecc/MiVeCCEdge-v0",
            entry_point="mivecc_env.single_agent:MiVeCCEdgeEnv",
            vector_entry_point="mivecc_env.single_agent:MiVeCCEdgeVectorEnv",
            max_episode_steps=None,
        )


def register_pettingzoo() -> bool:
    """Register the PettingZoo envs (:data:`PETTINGZOO_IDS`) with PettingZoo's registry.

    Idempotent. PettingZoo releases before 1.27 have no registry: nothing is registered there and
    this returns ``False`` (the module-level ``parallel_env()`` / ``env()`` work everywhere).
    """
    import pettingzoo

    if not hasattr(pettingzoo, "register"):
        return False
    for env_id, module in PETTINGZOO_IDS.items():
        for kind, registry, attr in (
            ("parallel", pettingzoo.parallel_registry, "parallel_env"),
            ("aec", pettingzoo.aec_registry, "env"),
        ):
            if env_id not in registry:
                pettingzoo.register(kind, env_id, entry_point=f"{module}:{attr}")
    return True


PETTINGZOO_IDS = {
    "mivecc/mivecc-v0": "mivecc_env.mivecc_v0",
    "mivecc/mivecc_edges-v0": "mivecc_env.mivecc_edges_v0",
    "mivecc/mivecc_vehicles-v0": "mivecc_env.mivecc_vehicles_v0",
}

register_gymnasium()
register_pettingzoo()
