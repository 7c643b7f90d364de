"""Single-agent Gymnasium view: the edge node of one intersection.

The agent controls the edge node of intersection ``intersection`` (default 0); the other edge
nodes and the cloud node send no action (their vehicles follow the on-board rules), and the
scheme is ``EE``. Observation ``Box(-1, 1, (K, K, 3))``, action ``Box(-a_max, a_max, (K,))``,
reward and ``info`` as the edge agent of :class:`mivecc_env.parallel_env.MiVeCCParallelEnv`.
Never terminated; truncated after ``max_steps``.

Example:
    >>> import gymnasium, mivecc_env
    >>> env = gymnasium.make("mivecc/MiVeCCEdge-v0", rows=1, cols=1, density=900)

Vectorised: ``gymnasium.make_vec("mivecc/MiVeCCEdge-v0", num_envs=N,
vectorization_mode="vector_entry_point", ...)`` gives :class:`MiVeCCEdgeVectorEnv`, N copies in
one :class:`mivecc_env.batched.BatchedMiVeCCEnv` (one simulator), with gymnasium's next-step
autoreset. Copy ``i`` runs exactly like ``gymnasium.make(...)`` reset with seed ``seed + i``
(the same trajectory as a ``SyncVectorEnv`` of the single env, autoresets included).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from mivecc_env.actions import checked_action
from mivecc_env.batched import REWARD_TERMS, BatchedMiVeCCEnv, BatchStep
from mivecc_env.config import ConfigError
from mivecc_env.parallel_env import MiVeCCParallelEnv, edge_agent
from mivecc_env.sim import checks


class MiVeCCEdgeEnv(gymnasium.Env):
    """The edge node of one intersection as a Gymnasium environment.

    Args:
        intersection: index ``row * cols + col`` of the controlled intersection.
        render_mode: ``None``, ``"rgb_array"`` or ``"human"`` (a matplotlib window, drawn
            at every reset and step; headless-safe, as for :class:`MiVeCCParallelEnv`).
        **overrides: config fields as for :class:`MiVeCCParallelEnv` (``scheme`` defaults to
            ``"EE"`` here).

    Raises:
        ConfigError: a bad config value or keyword, or ``intersection`` outside the grid.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(
        self, intersection: int = 0, render_mode: str | None = None, **overrides: Any
    ) -> None:
        overrides.setdefault("scheme", "EE")
        self._env = MiVeCCParallelEnv(render_mode=render_mode, **overrides)
        self.agent = edge_agent(_checked_intersection(intersection,
                                                      self._env.config.n_intersections))
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
        """An RGB frame (``render_mode="rgb_array"``), else ``None`` (``"human"`` draws)."""
        return self._env.render()

    def close(self) -> None:
        """Close the underlying environment."""
        self._env.close()


class MiVeCCEdgeVectorEnv(VectorEnv):
    """``num_envs`` copies of :class:`MiVeCCEdgeEnv` in one batched simulator.

    Observations ``(num_envs, K, K, 3)`` float32, actions ``(num_envs, K)`` [m/s^2], rewards,
    terminations and truncations ``(num_envs,)``; ``infos`` holds ``mask`` ``(num_envs, K)`` and
    the reward terms ``(num_envs,)`` (each with its ``_key`` mask, all True). Autoreset is
    gymnasium's next-step mode: the step after an episode ends resets that copy (its action is
    ignored, its reward is 0). Seeding follows :class:`MiVeCCEdgeEnv`: ``reset(seed=s)`` seeds
    copy ``i`` with ``s + i`` (or ``seed[i]`` for a list), and every later (auto)reset of a copy
    draws its seed from that copy's own generator.

    Args:
        num_envs: number of copies N >= 1.
        intersection: index of the controlled intersection (as :class:`MiVeCCEdgeEnv`).
        densities: (N,) demand of each copy [veh/lane/h] (default: the config's).
        **overrides: config fields (``scheme`` defaults to ``"EE"``).
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        intersection: int = 0,
        densities: Sequence[float] | None = None,
        max_episode_steps: int | None = None,
        **overrides: Any,
    ) -> None:
        overrides.setdefault("scheme", "EE")
        if max_episode_steps is not None:
            overrides.setdefault("max_steps", max_episode_steps)
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ConfigError(f"num_envs: must be an integer >= 1, got {num_envs!r}")
        self.env = BatchedMiVeCCEnv(batch_size=num_envs, densities=densities, observe={"edge"},
                                    **overrides)
        c = self.env.config
        self.intersection = _checked_intersection(intersection, c.n_intersections)
        self.num_envs = self.env.batch_size
        self.render_mode = None
        k = c.k_edge
        self.single_observation_space = gymnasium.spaces.Box(-1.0, 1.0, (k, k, 3), np.float32)
        self.single_action_space = gymnasium.spaces.Box(-c.a_max_mps2, c.a_max_mps2, (k,),
                                                        np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs = [seeding.np_random()[0] for _ in range(self.num_envs)]
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._all = np.ones(self.num_envs, dtype=bool)

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every copy (``seed``: an int ``s`` gives copy ``i`` the seed ``s + i``)."""
        del options
        if seed is None:
            seeds = [self._draw_seed(i) for i in range(self.num_envs)]
        else:
            seeds = checks.check_seed(seed, self.num_envs)
            if isinstance(seeds, int):
                seeds = [seeds + i for i in range(self.num_envs)]
            self._rngs = [seeding.np_random(x)[0] for x in seeds]
        self._autoreset[:] = False
        out = self.env.reset(seed=seeds)
        return out.edge_obs[:, self.intersection], self._infos(out)

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One step of every copy with ``(num_envs, K)`` accelerations [m/s^2]."""
        last = self.env._last  # padded columns of the last observation may hold NaN
        mask = None if last is None else last.edge_mask[:, self.intersection]
        act = checked_action(actions, "actions", self.action_space.shape,
                             self.env.config.a_max_mps2, mask)
        cols = np.full((self.num_envs, self.env.n_edge, self.env.k_edge), np.nan)
        cols[:, self.intersection] = act
        out = self.env.step_commands(cols, None)
        if self._autoreset.any():
            envs = np.flatnonzero(self._autoreset)
            out = self.env.reset_at(envs, seed=[self._draw_seed(i) for i in envs.tolist()])
        i = self.intersection
        self._autoreset = out.terminated | out.truncated
        return (out.edge_obs[:, i], out.edge_reward[:, i].copy(), out.terminated.copy(),
                out.truncated.copy(), self._infos(out))

    def summary(self) -> dict[str, np.ndarray]:
        """Episode metrics of every copy so far (``metrics.SUMMARY_KEYS`` -> (N,) arrays)."""
        return self.env.summary()

    def _draw_seed(self, i: int) -> int:
        # As MiVeCCEdgeEnv.reset does for an unseeded reset.
        return int(self._rngs[i].integers(0, 2**31 - 1))

    def _infos(self, out: BatchStep) -> dict[str, Any]:
        i = self.intersection
        infos: dict[str, Any] = {"mask": out.edge_mask[:, i], "_mask": self._all.copy()}
        for key in REWARD_TERMS:
            infos[key] = out.edge_terms[key][:, i].copy()
            infos[f"_{key}"] = self._all.copy()
        return infos


def _checked_intersection(intersection: object, n: int) -> int:
    """``intersection`` as an int in [0, n); ``ConfigError`` naming the field otherwise."""
    if (
        isinstance(intersection, bool)
        or not isinstance(intersection, int | np.integer)
        or not 0 <= intersection < n
    ):
        raise ConfigError(
            f"intersection: must be an integer in [0, {n - 1}], got {intersection!r}"
        )
    return int(intersection)
