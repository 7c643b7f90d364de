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
    With ``cloud_graphs="per_lane"`` (the paper's Algorithm 1) ``cloud_0`` observes one graph
    per through lane: ``Box(-1, 1, (n_lanes, K_cloud, K_cloud, 3), float32)``, its mask and
    action ``(n_lanes, K_cloud)``.

Action spaces:
    ``Box(-a_max, a_max, (K,), float32)``: acceleration [m/s^2] of each column's vehicle.
    Actions of padded columns are ignored (NaN there is accepted); an agent left out of the
    action dict sends no action (its vehicles follow the on-board rules). An unknown agent, a
    wrong shape, NaN/inf in a real column or a value outside the box raises ``ValueError``
    naming the agent, the expected box and the first bad column. A torch tensor (also with
    ``requires_grad=True``) is accepted as its values. Rule: :mod:`mivecc_env.actions`.

Signal agents:
    With ``control="signalized"`` and ``signal_agents=True``, agents ``signal_i`` follow
    ``cloud_0``: ``Discrete(2)`` phase actions, a ``(15,)`` float32 observation and a queue or
    pressure reward (see :mod:`mivecc_env.signal_agents`).

Rewards (named terms in ``infos[agent]``):
    ``edge_i``: ``reward_sv`` = ``reward_sv_weight`` x mean SV of its decision vehicles,
    ``reward_velocity`` = mean ``(v - reward_v_ref_mps)`` of the vehicles in its control area,
    ``reward_collision`` = ``-collision_penalty`` x vehicles removed by collision in its area.
    ``cloud_0``: ``reward_velocity`` over the vehicles it may pick (``cloud_pick_population``:
    by default those with a conflict point still ahead) and ``reward_collision`` over all
    collisions (``reward_sv`` is 0). The reward is the sum of the terms.

Infos:
    Every agent: ``mask`` and its reward terms. ``cloud_0`` (the whole-network node) also
    carries the episode summary so far (:data:`mivecc_env.metrics.SUMMARY_KEYS`, floats), so the
    summary is in the infos once per step, not once per agent; :meth:`MiVeCCParallelEnv.summary`
    returns it too. The keys are the same at reset and every step.

Implementation:
    An adapter of :class:`mivecc_env.batched.BatchedMiVeCCEnv` at B = 1 (one code path for
    observations and rewards); ``env.batched`` is that environment.

Starting state:
    An empty network; vehicles arrive by a Poisson process per entry lane (floored at
    ``min_headway_s``) and wait in an entry queue until their lane's entry is clear.

Episode end:
    Never terminated (continuous flow); truncated after ``max_steps`` steps.

Arguments:
    Any field of :class:`mivecc_env.config.MiVeCCConfig` as a keyword (``density`` is accepted
    for ``density_vplh``, ``max_cycles`` for ``max_steps``), or ``config=MiVeCCConfig(...)``;
    ``render_mode="rgb_array"`` or ``"human"``.

State:
    ``state()`` is the cloud node's state graph, in ``state_space``
    (``Box(-1, 1, (K_cloud, K_cloud, 3), float32)``), whatever the scheme.

Version history:
    v0: first release.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from mivecc_env import metrics
from mivecc_env import signal_agents as sig
from mivecc_env.actions import checked_action
from mivecc_env.batched import REWARD_TERMS, BatchedMiVeCCEnv, BatchStep
from mivecc_env.config import ConfigError, MiVeCCConfig, from_overrides
from mivecc_env.sim.checks import check_seed
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.state_graph import StateGraphs
from mivecc_env.viewer import HumanViewer

CLOUD_AGENT = "cloud_0"


def edge_agent(index: int) -> str:
    """Name of the edge agent of intersection ``index``."""
    return f"edge_{index}"


class MiVeCCParallelEnv(ParallelEnv):
    """PettingZoo parallel environment of MiVeCC (see the module docstring).

    Agents are ``edge_0 .. edge_{R*C-1}`` then ``cloud_0``; all of them act every step and all
    leave together at truncation. ``reset`` must be called before ``step``.

    Args:
        config: a :class:`MiVeCCConfig`; keyword ``overrides`` replace its fields.
        render_mode: ``None``, ``"rgb_array"`` (``render()`` returns a frame) or ``"human"``
            (a matplotlib window updated at every reset and step; headless-safe, see
            :mod:`mivecc_env.viewer`).
        **overrides: config fields (``density`` is accepted for ``density_vplh``, ``max_cycles``
            for ``max_steps``).

    Raises:
        ConfigError: an unknown keyword, a value out of range, a ``config`` that is not a
            :class:`MiVeCCConfig`, or an unsupported ``render_mode``.
    """

    metadata = {
        "render_modes": ["human", "rgb_array"],
        "name": "mivecc_v0",
        "is_parallelizable": True,
        "render_fps": 10,
    }

    def __init__(
        self,
        config: MiVeCCConfig | None = None,
        render_mode: str | None = None,
        signal_agents: bool = False,
        signal_reward: str = "queue",
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
        self._viewer: HumanViewer | None = None
        # Every agent has an observation, so both graphs are built whatever the scheme.
        self.batched = BatchedMiVeCCEnv(self.config, 1, observe={"edge", "cloud"},
                                        signal_agents=signal_agents,
                                        signal_reward=signal_reward)
        c = self.config
        n = c.n_intersections
        self.edge_agents = [edge_agent(i) for i in range(n)]
        self.signal_agents = ([sig.signal_agent(i) for i in range(n)]
                              if self.batched.signal_agents else [])
        self._signal_index = {a: i for i, a in enumerate(self.signal_agents)}
        self.possible_agents = [*self.edge_agents, CLOUD_AGENT, *self.signal_agents]
        self.agents: list[str] = []
        self._possible = frozenset(self.possible_agents)
        self._edge_index = {a: i for i, a in enumerate(self.edge_agents)}
        # observation and action shapes: (K, K, 3) and (K,); the cloud's with
        # cloud_graphs="per_lane": (n_lanes, K, K, 3) and (n_lanes, K)
        graph_shapes = {a: (c.k_edge, c.k_edge, 3) for a in self.edge_agents} | {
            CLOUD_AGENT: c.cloud_graph_shape}
        self._obs_spaces = {
            a: spaces.Box(-1.0, 1.0, shape, dtype=np.float32)
            for a, shape in graph_shapes.items()
        }
        self._act_spaces = {
            a: spaces.Box(-c.a_max_mps2, c.a_max_mps2, shape[:-2], dtype=np.float32)
            for a, shape in graph_shapes.items()
        }
        low, high = sig.observation_bounds(c)
        for a in self.signal_agents:
            self._obs_spaces[a] = spaces.Box(low, high, dtype=np.float32)
            self._act_spaces[a] = spaces.Discrete(sig.N_PHASES)
        self.state_space = spaces.Box(-1.0, 1.0, c.cloud_graph_shape, dtype=np.float32)
        # Accelerations are accepted up to this bound (float32 rounding of the box's edge).
        self._a_limit = c.a_max_mps2 + 1e-6
        self._column_shapes = [(a, self._act_spaces[a].shape)
                               for a in (*self.edge_agents, CLOUD_AGENT)]
        self._n_edge_columns = n * c.k_edge
        self._last: BatchStep | None = None

    # ------------------------------------------------------------------------------------
    @property
    def sim(self) -> Simulator:
        """The underlying simulator (batch size 1)."""
        return self.batched.sim

    @property
    def _edge(self) -> StateGraphs | None:
        return self.batched._edge

    @property
    def _cloud(self) -> StateGraphs | None:
        return self.batched._cloud

    def observation_space(self, agent: str) -> spaces.Box:
        """``Box(-1, 1, (K, K, 3), float32)`` of ``agent`` (the same object on every call;
        ``cloud_0``'s: ``config.cloud_graph_shape``); a signal agent's is ``Box(low, high,
        (15,), float32)`` (:mod:`..signal_agents`)."""
        return self._space(self._obs_spaces, agent, "observation_space")

    def action_space(self, agent: str) -> spaces.Space:
        """``Box(-a_max, a_max, (K,), float32)`` of ``agent`` (the same object on every call;
        ``cloud_0``'s: ``config.cloud_action_shape``); ``Discrete(2)`` (the phase wanted green)
        for a signal agent."""
        return self._space(self._act_spaces, agent, "action_space")

    def _space(self, spaces_of: dict[str, spaces.Space], agent: str, what: str) -> spaces.Space:
        """``spaces_of[agent]``; an unknown agent is a ``KeyError`` naming the agents."""
        try:
            return spaces_of[agent]
        except (KeyError, TypeError):
            raise KeyError(f"{what}: unknown agent {agent!r}; agents are "
                           f"{self.possible_agents}") from None

    @functools.cached_property
    def upper_bound_mps(self) -> float:
        """Theoretical upper bound of the average travel velocity [m/s] of this config."""
        return metrics.upper_bound_velocity_mps(self.config)

    # ------------------------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        """Empty the network and start a new episode.

        Args:
            seed: seeds this episode and the sequence of later unseeded resets.
            options: unused (accepted for API compatibility).

        Returns:
            Observations and infos of every agent.
        """
        if seed is not None:
            seed = check_seed(seed)
        self._last = out = self.batched.reset(seed)
        self.agents = list(self.possible_agents)
        if self.render_mode == "human":
            self.render()
        return self._observations(out), self._infos(out)

    def step(
        self, actions: dict[str, np.ndarray]
    ) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict]
    ]:
        """Apply the coordinators' accelerations and advance the network by one time step.

        Args:
            actions: ``agent -> (K,)`` accelerations [m/s^2]; an agent left out sends no
                action (its vehicles follow the on-board rules). A signal agent's action is
                the phase it wants green (0 / 1); one left out leaves its intersection to
                ``signal_controller``.

        Returns:
            ``(observations, rewards, terminations, truncations, infos)``, keyed by agent.

        Raises:
            RuntimeError: ``reset`` has not been called, or the episode has ended.
            ValueError: an unknown agent, or an action of the wrong shape, NaN/inf in a real
                column, or outside the action box (:mod:`mivecc_env.actions`)
                (a signal agent's: not an integer in {0, 1}).
        """
        if not self.agents:
            raise RuntimeError("step: call reset() first (or again after the episode ended)")
        edge_cols, cloud_cols = self._columns(actions)
        phases = self._phases(actions)
        self._last = out = self.batched.step_commands(edge_cols, cloud_cols, phases)
        agents = self.agents
        signal_rewards = [] if out.signal_reward is None else out.signal_reward[0].tolist()
        rewards = dict(zip(agents, [*out.edge_reward[0].tolist(), out.cloud_reward.item(0),
                                    *signal_rewards], strict=True))
        truncated = bool(out.truncated[0])
        terminations = dict.fromkeys(agents, False)
        truncations = dict.fromkeys(agents, truncated)
        obs, infos = self._observations(out), self._infos(out)
        if truncated:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terminations, truncations, infos

    # ------------------------------------------------------------------------------------
    def _columns(
        self, actions: dict[str, np.ndarray]
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Validated per-column actions: ``(1, n_edge, K_edge)`` (NaN rows for the edge agents
        left out) and ``(1, K_cloud)``, each ``None`` when no such agent acts."""
        if not isinstance(actions, Mapping):
            raise ValueError(
                f"actions: expected a dict agent -> (K,) array, got {type(actions).__name__}"
            )
        if not self._possible.issuperset(actions):
            unknown = sorted(map(str, set(actions) - self._possible))
            raise ValueError(
                f"actions: unknown agents {unknown}; agents are {self.possible_agents}"
            )
        every = self._every_column(actions)
        if every is not None:
            return every
        edge_cols = cloud_cols = None
        edges = [a for a in actions if a in self._edge_index]
        if edges:
            acts = self._checked_batch(edges, actions)
            if len(edges) == len(self.edge_agents) and edges == self.edge_agents:
                edge_cols = acts[None]
            else:
                edge_cols = np.full((1, len(self.edge_agents), self.config.k_edge), np.nan)
                edge_cols[0, [self._edge_index[a] for a in edges]] = acts
        if CLOUD_AGENT in actions:
            action = actions[CLOUD_AGENT]
            cloud = self._in_box(action, self._act_spaces[CLOUD_AGENT].shape)
            if cloud is None:
                cloud = self._check_action(CLOUD_AGENT, action)
            cloud_cols = cloud[None]
        return edge_cols, cloud_cols

    def _every_column(
        self, actions: Mapping[str, Any]
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The usual case in one conversion and one range check: every edge agent and the
        cloud act with numpy arrays of shape (K,), all inside the box. ``None`` otherwise (the
        general path then applies the same rule per agent and names any error)."""
        parts = []
        for agent, shape in self._column_shapes:
            action = actions.get(agent)
            if type(action) is not np.ndarray or action.shape != shape:
                return None
            parts.append(action.reshape(-1))
        try:
            flat = np.concatenate(parts, dtype=np.float64)
        except (TypeError, ValueError):
            return None
        lim = self._a_limit
        # NaN compares False (and min / max propagate it): NaN and inf take the general path.
        if not (flat.min() >= -lim and flat.max() <= lim):
            return None
        n = self._n_edge_columns
        return (flat[:n].reshape(1, len(self.edge_agents), -1),
                flat[n:].reshape(1, *self._act_spaces[CLOUD_AGENT].shape))

    def _phases(self, actions: Mapping[str, Any]) -> np.ndarray | None:
        """(1, n_int) phases of the signal agents (-1 for those left out), ``None`` if none."""
        if not self._signal_index:
            return None
        acting = [a for a in actions if a in self._signal_index]
        if not acting:
            return None
        phases = np.full((1, len(self.signal_agents)), -1, dtype=np.int64)
        for a in acting:
            phases[0, self._signal_index[a]] = sig.check_agent_action(a, actions[a])
        return phases

    def _commands(self, actions: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Per-slot edge and cloud commands (NaN where none) from the agents' actions."""
        edge_cols, cloud_cols = self._columns(actions)
        nan = np.full(self.sim.active.shape, np.nan)
        edge_cmd = nan if edge_cols is None else self.batched._commands(self._edge, edge_cols)
        cloud_cmd = (nan.copy() if cloud_cols is None
                     else self.batched._commands(self._cloud, cloud_cols[:, None, :]))
        return edge_cmd, cloud_cmd

    def _checked_batch(self, agents: list[str], actions: Mapping[str, Any]) -> np.ndarray:
        """(len(agents), K_edge) float64 actions of edge agents, validated as one array.

        The fast path converts and checks all of them at once; on any problem (a tensor, NaN
        in a padded column, a bad value) each action is checked on its own (:meth:`_check_action`)
        so that the rule is applied exactly and an error names the offending agent.
        """
        acts = self._in_box([actions[a] for a in agents], (len(agents), self.config.k_edge))
        if acts is None:
            acts = np.stack([self._check_action(a, actions[a]) for a in agents])
        return acts

    def _in_box(self, action: Any, shape: tuple[int, ...]) -> np.ndarray | None:
        """``action`` as a float64 array if it converts directly, has ``shape`` and every value
        is in the box; ``None`` otherwise (then the exact rule decides, and names the error)."""
        try:
            arr = np.asarray(action, dtype=np.float64)
        except (ValueError, TypeError, RuntimeError):
            return None
        if arr.shape != shape:
            return None
        # NaN compares False (and min / max propagate it), so NaN and inf take the exact path.
        lim = self._a_limit
        return arr if arr.min() >= -lim and arr.max() <= lim else None

    def check_action(self, agent: str, action: Any) -> None:
        """Raise what :meth:`step` would raise for ``action`` as ``agent``'s (a ``ValueError``
        naming the agent), judged against its last observation; nothing if it is valid. The
        AEC env (:func:`mivecc_env.mivecc_v0.env`) checks each action with it when it is given.
        """
        if (agent in self._edge_index or agent == CLOUD_AGENT) and self._in_box(
                action, self._act_spaces[agent].shape) is not None:
            return  # step's fast path accepts it as it is (:meth:`_in_box`)
        actions = {agent: action}
        self._columns(actions)  # step's checks of the agents and of edge and cloud actions
        self._phases(actions)  # a signal agent's phase

    def _check_action(self, agent: str, action: Any) -> np.ndarray:
        """``action`` as a float64 array, or ``ValueError`` naming the agent and the box.

        The rule is :func:`mivecc_env.actions.checked_action`; the padded columns are those of
        the agent's last observation (``infos[agent]["mask"]``).
        """
        last = self._last
        masks = None if last is None else (
            last.cloud_mask if agent == CLOUD_AGENT else last.edge_mask)
        mask = None if masks is None else (
            masks[0] if agent == CLOUD_AGENT else masks[0, self._edge_index[agent]])
        return checked_action(action, f"actions[{agent!r}]", self._act_spaces[agent].shape,
                              self.config.a_max_mps2, mask,
                              " (clip exploration noise to the action box)")

    def _observe(self) -> None:
        """Rebuild the state graphs of the current simulator state (after editing it)."""
        self._last = self.batched._observe_and_pack(None)

    def _observations(self, out: BatchStep) -> dict[str, np.ndarray]:
        """Observation of every live agent (views of the freshly built state graphs)."""
        if not self.agents:
            return {}
        signal = [] if out.signal_obs is None else list(out.signal_obs[0])
        return dict(zip(self.possible_agents, [*out.edge_obs[0], out.cloud_obs[0], *signal],
                        strict=True))

    def _infos(self, out: BatchStep) -> dict[str, dict]:
        """Per-agent infos: ``mask`` and the reward terms; ``cloud_0`` adds the summary.

        The set of keys is the same at reset and every step (TorchRL's wrapper needs that),
        and every value is numeric.
        """
        if not self.agents:
            return {}
        k_sv, k_vel, k_col = REWARD_TERMS
        terms = out.edge_terms
        infos: dict[str, dict] = {
            agent: {"mask": mask, k_sv: sv, k_vel: vel, k_col: col}
            for agent, mask, sv, vel, col in zip(
                self.edge_agents, out.edge_mask[0], terms[k_sv][0].tolist(),
                terms[k_vel][0].tolist(), terms[k_col][0].tolist(), strict=True)
        }
        terms = out.cloud_terms
        infos[CLOUD_AGENT] = {"mask": out.cloud_mask[0], k_sv: terms[k_sv].item(0),
                              k_vel: terms[k_vel].item(0), k_col: terms[k_col].item(0),
                              **self.summary()}
        if out.signal_terms is not None:
            terms = [out.signal_terms[k][0].tolist() for k in sig.SIGNAL_REWARD_TERMS]
            for agent, *values in zip(self.signal_agents, *terms, strict=True):
                infos[agent] = dict(zip(sig.SIGNAL_REWARD_TERMS, values, strict=True))
        return infos

    # ------------------------------------------------------------------------------------
    def summary(self) -> dict[str, float]:
        """Metrics of the current episode so far (see :mod:`mivecc_env.metrics`)."""
        return metrics.episode_summary(self.sim, 0)

    def render(self) -> np.ndarray | None:
        """An RGB frame of the network (``render_mode="rgb_array"``); ``"human"`` draws it in
        the window and returns ``None``, as does ``render_mode=None``."""
        if self.render_mode is None:
            return None
        from mivecc_env.render import render_rgb

        frame = render_rgb(self.sim, 0)
        if self.render_mode == "rgb_array":
            return frame
        if self._viewer is None:
            self._viewer = HumanViewer(self.metadata["name"], self.metadata["render_fps"])
        self._viewer.show(frame)
        return None

    def close(self) -> None:
        """Close the ``"human"`` window, if any."""
        if self._viewer is not None:
            self._viewer.close()

    def state(self) -> np.ndarray:
        """Global state: the cloud node's state graph (float32, (K_cloud, K_cloud, 3))."""
        if self._last is None:
            raise RuntimeError("state: call reset() first")
        return self._last.cloud_obs[0].copy()
