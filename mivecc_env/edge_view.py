"""Edge-only multi-agent view: the edge nodes as homogeneous agents, no ``cloud_0``.

Description:
    The same network as :class:`mivecc_env.parallel_env.MiVeCCParallelEnv`, but only the edge
    coordinators ``edge_0 .. edge_{R*C-1}`` are agents; the cloud node sends no action (its
    vehicles follow the on-board rules). Every agent has the same observation space
    ``Box(-1, 1, (K_edge, K_edge, 3), float32)`` and action space
    ``Box(-a_max, a_max, (K_edge,), float32)``, and all live for the whole episode, so
    parameter-sharing tools take it as it is: SuperSuit's ``pettingzoo_env_to_vec_env_v1`` /
    ``concat_vec_envs_v1`` (then Stable-Baselines3), RLlib's ``ParallelPettingZooEnv`` with one
    shared policy, BenchMARL's homogeneous groups.

    Observations, rewards, ``infos`` (``mask`` and the reward terms) and truncation are the edge
    agents' entries of the full environment; ``state()`` is the cloud node's state graph.

Arguments:
    Any field of :class:`mivecc_env.config.MiVeCCConfig` as a keyword, as for the full
    environment; ``scheme`` defaults to ``"EE"`` here (``"E"`` ignores the actions; ``"EEC"``
    is rejected, there is no cloud agent to act). ``render_mode`` and ``max_cycles`` as there.

Version history:
    v0: first release.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from mivecc_env.config import ConfigError
from mivecc_env.parallel_env import CLOUD_AGENT, MiVeCCParallelEnv


class MiVeCCEdgesParallelEnv(ParallelEnv):
    """The edge nodes of :class:`MiVeCCParallelEnv` as the only (homogeneous) agents.

    Args:
        render_mode: as for :class:`MiVeCCParallelEnv`.
        **overrides: config fields (``scheme`` defaults to ``"EE"``; ``"EEC"`` is rejected).

    Raises:
        ConfigError: a bad config value or keyword, or ``scheme="EEC"``.
    """

    def __init__(self, render_mode: str | None = None, **overrides: Any) -> None:
        overrides.setdefault("scheme", "EE")
        self._env = MiVeCCParallelEnv(render_mode=render_mode, **overrides)
        if self._env.config.scheme == "EEC":
            raise ConfigError(
                "scheme: the edge-only view has no cloud agent, so 'EEC' is not allowed; "
                "use 'EE' (or 'E'), or the full environment mivecc_v0.parallel_env()"
            )
        self.metadata = {**self._env.metadata, "name": "mivecc_edges_v0"}
        self.render_mode = render_mode
        self.config = self._env.config
        self.possible_agents = [a for a in self._env.possible_agents if a != CLOUD_AGENT]
        self.agents: list[str] = []
        self._started = False
        # Global state for centralised critics: the cloud node's view of the whole network.
        self.state_space: spaces.Box = self._env.observation_space(CLOUD_AGENT)

    @property
    def parallel_env(self) -> MiVeCCParallelEnv:
        """The full environment underneath (edge agents and ``cloud_0``)."""
        return self._env

    def observation_space(self, agent: str) -> spaces.Box:
        """``Box(-1, 1, (K_edge, K_edge, 3), float32)``, the same for every agent."""
        return self._env.observation_space(self._edge_agent(agent, "observation_space"))

    def action_space(self, agent: str) -> spaces.Box:
        """``Box(-a_max, a_max, (K_edge,), float32)``, the same for every agent."""
        return self._env.action_space(self._edge_agent(agent, "action_space"))

    def _edge_agent(self, agent: str, what: str) -> str:
        """``agent`` if it is one of this env's agents, else a ``KeyError`` naming them."""
        if agent not in self.possible_agents:
            raise KeyError(f"{what}: unknown agent {agent!r}; agents are "
                           f"{self.possible_agents}")
        return agent

    def check_action(self, agent: str, action: Any) -> None:
        """Raise what :meth:`step` would raise for ``action`` as ``agent``'s (the full env's
        :meth:`~mivecc_env.parallel_env.MiVeCCParallelEnv.check_action`, ``cloud_0``
        refused); nothing if it is valid."""
        if agent not in self.possible_agents:
            raise ValueError(f"actions: unknown agents [{str(agent)!r}]; agents are "
                             f"{self.possible_agents}")
        self._env.check_action(agent, action)

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        """Start an episode (seeding as for the full environment).

        The first reset of an env never seeded draws its seed from fresh OS entropy, so copies
        made before it (SuperSuit's ``concat_vec_envs_v1`` pickles the env) do not all see the
        same traffic; later unseeded resets continue each copy's own sequence.
        """
        if seed is None and not self._started:
            seed = int(np.random.SeedSequence().generate_state(1, np.uint64)[0]) >> 1
        self._started = True
        obs, infos = self._env.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        return self._drop_cloud(obs), self._drop_cloud(infos)

    def step(
        self, actions: dict[str, np.ndarray]
    ) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict]
    ]:
        """One step with the edge agents' ``(K_edge,)`` accelerations [m/s^2].

        Raises:
            ValueError: an action for ``cloud_0`` or an unknown agent, or a bad action (as for
                the full environment).
            RuntimeError: ``reset`` has not been called, or the episode has ended.
        """
        if isinstance(actions, dict) and CLOUD_AGENT in actions:
            raise ValueError(
                f"actions: the edge-only view has no agent {CLOUD_AGENT!r}; "
                f"agents are {self.possible_agents}"
            )
        out = self._env.step(actions)
        self.agents = [a for a in self._env.agents if a != CLOUD_AGENT]
        obs, rewards, terms, truncs, infos = (self._drop_cloud(d) for d in out)
        return obs, rewards, terms, truncs, infos

    @staticmethod
    def _drop_cloud(d: dict[str, Any]) -> dict[str, Any]:
        return {a: v for a, v in d.items() if a != CLOUD_AGENT}

    def state(self) -> np.ndarray:
        """The cloud node's state graph (float32, ``(K_cloud, K_cloud, 3)``)."""
        return self._env.state()

    def summary(self) -> dict[str, float]:
        """Metrics of the current episode so far (see :mod:`mivecc_env.metrics`)."""
        return self._env.summary()

    def render(self) -> np.ndarray | None:
        """As :meth:`MiVeCCParallelEnv.render`."""
        return self._env.render()

    def close(self) -> None:
        """Close the underlying environment."""
        self._env.close()
