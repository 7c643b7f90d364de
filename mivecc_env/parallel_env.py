"""The MiVeCC PettingZoo ``ParallelEnv``: edge coordinators and the cloud coordinator.

Description:
    A grid of R x C unsignalized intersections with continuous Poisson traffic. Every vehicle is
    an end node that drives by on-board safety rules (Algorithm 3 of the paper). The agents are
    the coordinators: ``edge_i`` for intersection ``i`` (``i = row * C + col``) and ``cloud_0``
    for the whole network. Each observes a state graph and outputs one acceleration per column,
    which the chosen vehicles fuse with their own rule (``scheme``: ``E`` ignores both
    coordinators, ``EE`` uses the edge nodes, ``EEC`` both).

Observation spaces:
    ``edge_i``: ``Box(-1, 1, (K_edge, K_edge, 3), float32)`` (15 x 15 x 3 by default);
    ``cloud_0``: ``Box(-1, 1, (K_cloud, K_cloud, 3), float32)`` (60 x 60 x 3). Column ``j`` is
    decision vehicle ``j``, row 0 the vehicle itself, rows ``1..K-1`` its nearest reference
    vehicles; channels position, velocity, acceleration (see ``mivecc_env.sim.state_graph``).
    Which columns are real vehicles is ``infos[agent]["mask"]`` (float32, shape ``(K,)``).

Action spaces:
    ``Box(-a_max, a_max, (K,), float32)``: acceleration [m/s^2] of each column's vehicle.
    Actions of padded columns are ignored. A wrong shape, a NaN/inf or a value outside the box
    raises ``ValueError``.

Rewards (named terms in ``infos[agent]``):
    ``edge_i``: ``reward_sv`` = ``reward_sv_weight`` x mean SV of its decision vehicles,
    ``reward_velocity`` = mean ``(v - reward_v_ref_mps)`` of the vehicles in its control area,
    ``reward_collision`` = ``-collision_penalty`` x vehicles removed by collision in its area.
    ``cloud_0``: ``reward_velocity`` over the whole network and ``reward_collision`` over all
    collisions (``reward_sv`` is 0). The reward is the sum of the terms.

Starting state:
    An empty network; vehicles arrive by a Poisson process per entry lane (floored at
    ``min_headway_s``) and wait in an entry queue until their lane's entry is clear.

Episode end:
    Never terminated (continuous flow); truncated after ``max_steps`` steps.

Arguments:
    Any field of :class:`mivecc_env.config.MiVeCCConfig` as a keyword (``density`` is accepted
    for ``density_vplh``), or ``config=MiVeCCConfig(...)``; ``render_mode="rgb_array"``.

Version history:
    v0: first release.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from mivecc_env import metrics
from mivecc_env.config import ConfigError, MiVeCCConfig, from_overrides
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.state_graph import StateGraphs, cloud_graphs, edge_graphs
from mivecc_env.sim.virtual_lane import density_indicator

CLOUD_AGENT = "cloud_0"


def edge_agent(index: int) -> str:
    """Name of the edge agent of intersection ``index``."""
    return f"edge_{index}"


class MiVeCCParallelEnv(ParallelEnv):
    """PettingZoo parallel environment of MiVeCC (see the module docstring)."""

    metadata = {
        "render_modes": ["rgb_array"],
        "name": "mivecc_v0",
        "is_parallelizable": True,
        "render_fps": 10,
    }

    def __init__(
        self,
        config: MiVeCCConfig | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        if config is not None and not isinstance(config, MiVeCCConfig):
            raise ConfigError(f"config: must be a MiVeCCConfig, got {type(config).__name__}")
        self.config = from_overrides(config, **overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(
                f"render_mode: must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        self.render_mode = render_mode
        self.sim = Simulator(self.config, batch_size=1, seed=0)
        n = self.config.n_intersections
        self.edge_agents = [edge_agent(i) for i in range(n)]
        self.possible_agents = [*self.edge_agents, CLOUD_AGENT]
        self.agents: list[str] = []
        c = self.config
        self._k = {a: c.k_edge for a in self.edge_agents} | {CLOUD_AGENT: c.k_cloud}
        self._obs_spaces = {
            a: spaces.Box(-1.0, 1.0, (k, k, 3), dtype=np.float32) for a, k in self._k.items()
        }
        self._act_spaces = {
            a: spaces.Box(-c.a_max_mps2, c.a_max_mps2, (k,), dtype=np.float32)
            for a, k in self._k.items()
        }
        self._seed_rng = np.random.default_rng()
        self._edge: StateGraphs | None = None
        self._cloud: StateGraphs | None = None

    # ------------------------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Box:
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self._act_spaces[agent]

    @functools.cached_property
    def upper_bound_mps(self) -> float:
        return metrics.upper_bound_velocity_mps(self.config)

    # ------------------------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        if seed is not None:
            self._seed_rng = np.random.default_rng(seed)
        sim_seed = int(self._seed_rng.integers(0, 2**63 - 1))
        self.sim.reset(sim_seed)
        self.agents = list(self.possible_agents)
        self._observe()
        zero = {a: 0.0 for a in self.possible_agents}
        return self._observations(), self._infos(zero, zero, zero)

    def step(self, actions: dict[str, np.ndarray]) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict]
    ]:
        if not self.agents:
            raise RuntimeError("step: call reset() first (or again after the episode ended)")
        edge_cmd, cloud_cmd = self._commands(actions)
        events = self.sim.step(edge_cmd, cloud_cmd)
        self._observe()
        r_sv, r_vel, r_col = self._reward_terms(events)
        rewards = {a: float(r_sv[a] + r_vel[a] + r_col[a]) for a in self.agents}
        truncated = self.sim.step_count >= self.config.max_steps
        terminations = {a: False for a in self.agents}
        truncations = {a: truncated for a in self.agents}
        obs, infos = self._observations(), self._infos(r_sv, r_vel, r_col)
        if truncated:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    # ------------------------------------------------------------------------------------
    def _commands(self, actions: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        unknown = set(actions) - set(self.possible_agents)
        if unknown:
            raise ValueError(f"actions: unknown agents {sorted(unknown)}; "
                             f"agents are {self.possible_agents}")
        shape = self.sim.active.shape
        edge_cmd = np.full(shape, np.nan)
        cloud_cmd = np.full(shape, np.nan)
        for agent, act in actions.items():
            act = self._check_action(agent, act)
            graphs, node = (
                (self._cloud, 0) if agent == CLOUD_AGENT else (self._edge, int(agent[5:]))
            )
            slots = graphs.slot[0, node]
            real = slots >= 0
            target = cloud_cmd if agent == CLOUD_AGENT else edge_cmd
            target.ravel()[slots[real]] = act[real]
        return edge_cmd, cloud_cmd

    def _check_action(self, agent: str, action: Any) -> np.ndarray:
        space = self._act_spaces[agent]
        arr = np.asarray(action, dtype=np.float64)
        if arr.shape != space.shape:
            raise ValueError(f"actions[{agent!r}]: expected shape {space.shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"actions[{agent!r}]: contains NaN or inf")
        lim = self.config.a_max_mps2
        if np.any(np.abs(arr) > lim + 1e-6):
            raise ValueError(
                f"actions[{agent!r}]: accelerations must be in [{-lim}, {lim}] m/s^2, got "
                f"min {arr.min():.3f} max {arr.max():.3f} (clip exploration noise to the box)"
            )
        return arr

    def _observe(self) -> None:
        sim, c = self.sim, self.config
        view = sim.view
        v = sim.v.ravel()[view.vehicle]
        a = sim.a.ravel()[view.vehicle]
        self._edge = edge_graphs(sim.network, view, sim.safety.sv, v, a, 1, c)
        di = density_indicator(view, c.di_n)
        self._cloud = cloud_graphs(sim.network, view, di, v, a, 1, c)
        self._v_view = v

    def _observations(self) -> dict[str, np.ndarray]:
        obs = {a: self._edge.obs[0, i] for i, a in enumerate(self.edge_agents)}
        obs[CLOUD_AGENT] = self._cloud.obs[0, 0]
        return {a: obs[a] for a in self.agents}

    def _reward_terms(self, events: Any) -> tuple[dict, dict, dict]:
        c, sim = self.config, self.sim
        n_int = c.n_intersections
        view = sim.view
        area = sim.network.control_area(view.lane, view.s)
        inside = area >= 0
        dv = self._v_view - c.reward_v_ref_mps
        count = np.bincount(area[inside], minlength=n_int)
        vel_sum = np.bincount(area[inside], dv[inside], minlength=n_int)
        vel = np.where(count > 0, vel_sum / np.maximum(count, 1), 0.0)
        idx = self._edge.view_index[0]
        real = idx >= 0
        sv = sim.safety.sv
        sv_sum = np.where(real, sv[np.maximum(idx, 0)] if sv.size else 0.0, 0.0).sum(axis=1)
        n_dec = real.sum(axis=1)
        sv_mean = np.where(n_dec > 0, sv_sum / np.maximum(n_dec, 1), 0.0)
        hit_area = events.collided_area[events.collided_area >= 0]
        hits = np.bincount(hit_area, minlength=n_int)
        r_sv = {a: c.reward_sv_weight * float(sv_mean[i]) for i, a in enumerate(self.edge_agents)}
        r_vel = {a: float(vel[i]) for i, a in enumerate(self.edge_agents)}
        r_col = {a: -c.collision_penalty * float(hits[i]) for i, a in enumerate(self.edge_agents)}
        r_sv[CLOUD_AGENT] = 0.0
        r_vel[CLOUD_AGENT] = float(dv.mean()) if dv.size else 0.0
        r_col[CLOUD_AGENT] = -c.collision_penalty * float(events.collided_vehicles[0])
        return r_sv, r_vel, r_col

    def _infos(self, r_sv: dict, r_vel: dict, r_col: dict) -> dict[str, dict]:
        summary = self.summary()
        infos = {}
        for i, agent in enumerate(self.agents):
            graphs, node = (
                (self._cloud, 0) if agent == CLOUD_AGENT else (self._edge, i)
            )
            infos[agent] = {
                "mask": graphs.mask[0, node],
                "reward_sv": r_sv[agent],
                "reward_velocity": r_vel[agent],
                "reward_collision": r_col[agent],
                **summary,
            }
        return infos

    # ------------------------------------------------------------------------------------
    def summary(self) -> dict[str, float]:
        """Metrics of the current episode so far (see :mod:`mivecc_env.metrics`)."""
        return metrics.episode_summary(self.sim, 0)

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        from mivecc_env.render import render_rgb

        return render_rgb(self.sim, 0)

    def close(self) -> None:
        pass

    def state(self) -> np.ndarray:
        """Global state: the cloud node's state graph (float32, (K_cloud, K_cloud, 3))."""
        return self._cloud.obs[0, 0].copy()
