"""Vehicles as PettingZoo agents: CoMADDPG's view of the network as a ParallelEnv.

Description:
    Every vehicle inside an intersection's control area is an agent ``vehicle_<id>`` (``id``:
    the order in which vehicles entered the network, from 0). It observes itself and its
    ``k - 1`` nearest reference vehicles on its virtual lane (``Box(-1, 1, (k, 3), float32)``:
    one column of an edge state graph, :mod:`mivecc_env.vehicle_agents`) and sets its own
    acceleration (``Box(-a_max, a_max, (1,), float32)``), executed without the end-node rules
    (the velocity bounds hold). Agents come and go: a vehicle joins when it enters a control
    area and ends (``terminated``) when it leaves the areas, leaves the network or collides,
    and it does not come back (on a grid whose areas leave gaps, a vehicle that re-enters an
    area is driven by the rules). Outside the areas the rules drive. The episode is truncated
    after ``max_steps`` steps; steps in which no vehicle is in any area are run by the rules
    inside one ``step`` (and at ``reset``), so ``agents`` is empty only once the episode ends.

    Reward per agent and step (CoMADDPG's, :func:`mivecc_env.vehicle_agents.vehicle_rewards`):
    ``(v' - v_max) / (v_max - v_floor) + safety_weight * min(SV', 0) / 20 -
    collision_penalty`` if it collided. ``infos[agent]`` holds ``"slot"`` (its vehicle slot)
    and ``"env_step"``; the whole network's running summary is ``summary()``.

Arguments:
    ``k`` (8), ``collision_penalty`` (20.0), ``safety_weight`` (2.0), and any field of
    :class:`mivecc_env.config.MiVeCCConfig` as a keyword (``rows``, ``cols``, ``density``,
    ``max_steps``, ...), except the ones that make vehicles agents (``control`` unsignalized,
    ``scheme`` EE, no ``safety_shield``, ``model`` paper: another value is a ``ConfigError``).
    ``min_headway_s`` must be above 0 (it bounds the vehicles of an episode, hence
    ``possible_agents``). Only ``render_mode=None``.

Version history:
    v0: first release.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from mivecc_env.actions import to_host
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.config import ConfigError, from_overrides
from mivecc_env.vehicle_agents import (
    VEHICLE_AGENT_FIELDS,
    VehicleAgents,
    follow,
    observe_vehicles,
    vehicle_commands,
    vehicle_rewards,
)


class MiVeCCVehiclesParallelEnv(ParallelEnv):
    """The vehicles inside the control areas as agents (module docstring).

    Raises:
        ConfigError: a bad config value or keyword, ``k`` < 2, a negative or non-finite reward
            weight, a field of ``vehicle_agents.VEHICLE_AGENT_FIELDS`` set otherwise,
            ``min_headway_s = 0``, or a ``render_mode``.
    """

    metadata = {"name": "mivecc_vehicles_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, render_mode: str | None = None, k: int = 8,
                 collision_penalty: float = 20.0, safety_weight: float = 2.0,
                 **overrides: Any) -> None:
        if render_mode is not None:
            raise ConfigError(f"render_mode: mivecc_vehicles_v0 has none, got {render_mode!r}")
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 2 <= k <= 64:
            raise ConfigError(f"k: must be an integer in [2, 64], got {k!r}")
        for name, value in (("collision_penalty", collision_penalty),
                            ("safety_weight", safety_weight)):
            if isinstance(value, bool) or not isinstance(value, int | float) or not (
                    math.isfinite(value) and value >= 0):
                raise ConfigError(f"{name}: must be a finite number >= 0, got {value!r}")
        for name, value in VEHICLE_AGENT_FIELDS.items():
            if overrides.get(name, value) != value:
                raise ConfigError(f"{name}: vehicle agents need {name}={value!r}, "
                                  f"got {overrides[name]!r}")
        self.config = c = from_overrides(None, **{**overrides, **VEHICLE_AGENT_FIELDS})
        if c.min_headway_s <= 0:
            raise ConfigError("min_headway_s: must be > 0 for mivecc_vehicles_v0 (it bounds "
                              f"the vehicles of an episode), got {c.min_headway_s}")
        self.render_mode = None
        self.k = int(k)
        self.collision_penalty, self.safety_weight = float(collision_penalty), float(
            safety_weight)
        self._env = BatchedMiVeCCEnv(c, batch_size=1, observe=())
        per_lane = math.floor(c.max_steps * c.dt_s / c.min_headway_s + 1e-9) + 1
        n_lanes = int(self._env.sim.network.n_lanes)
        self.possible_agents = [f"vehicle_{i}" for i in range(n_lanes * per_lane)]
        self.agents: list[str] = []
        self._live: list[str] = []  # the names of self._agents (self.agents is the user's)
        self._agents: VehicleAgents | None = None
        self._retired = np.zeros(len(self.possible_agents), dtype=bool)
        self._obs_space = spaces.Box(-1.0, 1.0, (self.k, 3), np.float32)
        self._act_space = spaces.Box(-c.a_max_mps2, c.a_max_mps2, (1,), np.float32)

    def observation_space(self, agent: str) -> spaces.Box:
        """``Box(-1, 1, (k, 3), float32)``, one object for every agent."""
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Box:
        """``Box(-a_max, a_max, (1,), float32)`` [m/s^2], one object for every agent."""
        return self._act_space

    # ------------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        """Restart from an empty network (``seed``: the demand's) and run the rules until a
        vehicle is in a control area."""
        self._env.reset(seed=seed)
        self._retired[:] = False
        self._agents = self._observe()
        self._advance_while_empty()
        self._live = self._names(self._agents)
        self.agents = list(self._live)
        return (self._observations(self._agents, self._live),
                self._infos(self._agents, self._live))

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """Apply every live agent's acceleration and advance one step (a missing or unknown
        agent, or an action of the wrong shape, NaN/inf or outside the box, is a ``ValueError``
        naming the agent)."""
        agents = self._agents
        if agents is None:
            raise RuntimeError("step: call reset() first")
        if not self.agents:
            raise RuntimeError("step: the episode has ended (no agents); call reset()")
        names = self._live  # the names of ``agents``, made when they were observed
        accel = self._accelerations(actions, names)
        self._env.step_vehicles(vehicle_commands(agents, accel, 1))
        nxt = self._observe()
        found, _ = follow(agents, nxt)
        reward = vehicle_rewards(agents, accel, nxt, self._env.sim.last_events, self.config,
                                 self.collision_penalty, self.safety_weight)
        self._retired[agents.vid[~found]] = True
        self._agents = nxt
        if not len(nxt):
            self._advance_while_empty()
        live = self._names(self._agents)
        done = bool(self._env.episode_steps[0] >= self.config.max_steps)
        old = set(names)
        # at the end no agent joins: the entries are those of the agents that acted
        new = [] if done else [a for a in live if a not in old]
        current = {a: o for a, o in self._observations(self._agents, live).items()
                   if a in old or not done}
        obs = {**{a: np.zeros((self.k, 3), np.float32) for a in names}, **current}
        rewards = {**dict(zip(names, reward.tolist(), strict=True)), **dict.fromkeys(new, 0.0)}
        terminated = {**dict(zip(names, (~found).tolist(), strict=True)),
                      **dict.fromkeys(new, False)}
        truncated = {a: done and not terminated[a] for a in obs}
        infos = {**{a: {} for a in names},
                 **{a: i for a, i in self._infos(self._agents, live).items() if a in obs}}
        self._live = live
        self.agents = [] if done else list(live)
        return obs, rewards, terminated, truncated, infos

    def summary(self) -> dict[str, float]:
        """The network's episode metrics so far (:data:`mivecc_env.metrics.SUMMARY_KEYS`)."""
        return {key: float(value[0]) for key, value in self._env.summary().items()}

    def close(self) -> None:
        """Nothing to release."""

    # ------------------------------------------------------------------------------------
    def _observe(self) -> VehicleAgents:
        """The vehicles in the control areas that have not been agents before and left."""
        agents = observe_vehicles(self._env.sim, self.k)
        keep = ~self._retired[agents.vid]
        if keep.all():
            return agents
        return _subset(agents, keep)

    def _advance_while_empty(self) -> None:
        """Run the rules while no vehicle is an agent, up to the episode's end."""
        while not len(self._agents) and self._env.episode_steps[0] < self.config.max_steps:
            self._env.step_commands(None, None)
            self._agents = self._observe()

    def check_action(self, agent: str, action: Any) -> None:
        """Raise what :meth:`step` would raise for ``action`` as ``agent``'s (a ``ValueError``
        naming the agent); nothing if it is valid. The AEC env
        (:func:`mivecc_env.mivecc_vehicles_v0.env`) checks each action with it when it is given.
        """
        if agent not in self.agents:
            raise ValueError(f"actions: {agent!r} is not a live agent")
        self._checked_acceleration(agent, action)

    def _accelerations(self, actions: dict[str, Any], names: list[str]) -> np.ndarray:
        """(n,) accelerations [m/s^2] of the live agents, in agent order, checked."""
        if not isinstance(actions, dict):
            raise ValueError(f"actions: expected a dict agent -> action, got "
                             f"{type(actions).__name__}")
        unknown = sorted(set(actions) - set(names))
        if unknown:
            raise ValueError(f"actions: {unknown[0]!r} is not a live agent")
        missing = [name for name in names if name not in actions]
        if missing:
            raise ValueError(f"actions: no action for live agent {missing[0]!r}")
        a_max = self.config.a_max_mps2
        try:  # all at once: one array op instead of one check per vehicle
            values = np.asarray([actions[name] for name in names], dtype=np.float64)
        except (TypeError, ValueError, RuntimeError):  # (RuntimeError: a tensor needing grad)
            values = None
        if values is not None and values.shape in ((len(names),), (len(names), 1)) and bool(
                np.all(np.abs(values) <= a_max + 1e-6)):  # (NaN fails the comparison)
            return np.clip(values.reshape(len(names)), -a_max, a_max)
        # some action is bad (named by the per-vehicle check) or a tensor (taken by its values)
        return np.array([self._checked_acceleration(name, actions[name]) for name in names])

    def _checked_acceleration(self, name: str, action: Any) -> float:
        """``action`` as one acceleration [m/s^2], or a ``ValueError`` naming the agent and the
        box (a value past the box's edge by float32 rounding only is put on the edge)."""
        a_max = self.config.a_max_mps2
        try:
            value = np.asarray(to_host(action), dtype=np.float64)
        except (TypeError, ValueError):
            value = np.full(2, np.nan)  # not a number: refused below, naming the agent
        if value.shape not in ((), (1,)) or not np.isfinite(value).all() or (
                abs(float(value.reshape(-1)[0])) > a_max + 1e-6):
            raise ValueError(f"actions[{name!r}]: must be one finite acceleration in "
                             f"[-{a_max}, {a_max}] m/s^2 (shape (1,)), got {action!r}")
        return float(np.clip(value.reshape(-1)[0], -a_max, a_max))

    def _names(self, agents: VehicleAgents) -> list[str]:
        return [f"vehicle_{v}" for v in agents.vid.tolist()]

    def _observations(self, agents: VehicleAgents, names: list[str]) -> dict[str, np.ndarray]:
        """Each agent's observation under its name (``names``: :meth:`_names` of ``agents``)."""
        return dict(zip(names, agents.obs, strict=True))

    def _infos(self, agents: VehicleAgents, names: list[str]) -> dict[str, dict]:
        """Each agent's info under its name (``names``: :meth:`_names` of ``agents``)."""
        step = int(self._env.episode_steps[0])
        return {name: {"slot": int(slot), "env_step": step}
                for name, slot in zip(names, agents.slot.tolist(), strict=True)}


def _subset(agents: VehicleAgents, keep: np.ndarray) -> VehicleAgents:
    """The agents where ``keep``, their reference rows renumbered (-1 for those dropped)."""
    index = np.full(len(agents) + 1, -1, dtype=np.int64)
    index[np.flatnonzero(keep)] = np.arange(int(keep.sum()))
    return VehicleAgents(
        obs=agents.obs[keep], env=agents.env[keep], slot=agents.slot[keep],
        vid=agents.vid[keep], ref_agent=index[agents.ref_agent[keep]],
        velocity=agents.velocity[keep], sv=agents.sv[keep], capacity=agents.capacity,
    )
