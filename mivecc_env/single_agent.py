"""Single-agent Gymnasium view: the edge node of one intersection.

The agent controls the edge node of intersection ``intersection`` (default 0); the other edge
nodes and the cloud node send no action (their vehicles follow the on-board rules), and the
scheme is ``EE``. Observation ``Box(-1, 1, (K, K, 3))``, action ``Box(-a_max, a_max, (K,))``,
reward and ``info`` as the edge agent of :class:`mivecc_env.parallel_env.MiVeCCParallelEnv`.
Never terminated; truncated after ``max_steps``.

Example:
    >>> import gymnasium, mivecc_env
    >>> env = gymnasium.make("mivecc/MiVeCCEdge-v0", rows=1, cols=1, density=900)
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from mivecc_env.config import ConfigError
from mivecc_env.parallel_env import MiVeCCParallelEnv, edge_agent


class MiVeCCEdgeEnv(gymnasium.Env):
    """The edge node of one intersection as a Gymnasium environment.

    Args:
        intersection: index ``row * cols + col`` of the controlled intersection.
        render_mode: ``None`` or ``"rgb_array"``.
        **overrides: config fields as for :class:`MiVeCCParallelEnv` (``scheme`` defaults to
            ``"EE"`` here).

    Raises:
        ConfigError: a bad config value or keyword, or ``intersection`` outside the grid.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self, intersection: int = 0, render_mode: str | None = None, **overrides: Any
    ) -> None:
        overrides.setdefault("scheme", "EE")
        self._env = MiVeCCParallelEnv(render_mode=render_mode, **overrides)
        n = self._env.config.n_intersections
        if (
            isinstance(intersection, bool)
            or not isinstance(intersection, int | np.integer)
            or not 0 <= intersection < n
        ):
            raise ConfigError(
                f"intersection: must be an integer in [0, {n - 1}], got {intersection!r}"
            )
        self.agent = edge_agent(int(intersection))
        self.observation_space = self._env.observation_space(self.agent)
        self.action_space = self._env.action_space(self.agent)
        self.render_mode = render_mode

    @property
    def parallel_env(self) -> MiVeCCParallelEnv:
        """The underlying multi-agent environment."""
        return self._env

    def reset(
        self, *, seed: int | None = None, options: dict | None = None
    ) -> tuple[np.ndarray, dict]:
        """Start an episode; an unseeded reset draws its seed from ``self.np_random``."""
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        obs, infos = self._env.reset(seed=seed, options=options)
        return obs[self.agent], infos[self.agent]

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """One step with this edge node's ``(K,)`` accelerations [m/s^2]."""
        obs, rewards, terms, truncs, infos = self._env.step({self.agent: action})
        return (
            obs[self.agent],
            rewards[self.agent],
            terms[self.agent],
            truncs[self.agent],
            infos[self.agent],
        )

    def render(self) -> np.ndarray | None:
        """An RGB frame (``render_mode="rgb_array"``), else ``None``."""
        return self._env.render()

    def close(self) -> None:
        """Close the underlying environment."""
        self._env.close()
