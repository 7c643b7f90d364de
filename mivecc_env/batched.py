"""B MiVeCC environments in one simulator: arrays with a leading batch axis, no agent dicts.

:class:`BatchedMiVeCCEnv` is the one code path for observations and rewards: the PettingZoo
``ParallelEnv`` / AEC envs are adapters of it at B = 1, the gymnasium vector env and the native
TorchRL env (``mivecc_agents``) use it at any B. It needs numpy only.

Semantics (details in ``docs/batched.md``):

* Environment ``b`` of a batch is bit-identical to a B = 1 run with the same seed and demand
  (observations, masks, rewards, summaries), whatever the other environments do.
* Seeds: every environment owns a seed generator. ``reset(seed=s)`` with an int seeds
  environment ``b`` with ``s + b`` (so B = 1 with seed ``s`` is :class:`MiVeCCParallelEnv`
  reset with ``seed=s``); a sequence gives one seed per environment; ``None`` continues every
  environment's own sequence. Each episode of environment ``b`` draws its simulator seed from
  that generator, exactly like the ParallelEnv does.
* Partial reset: :meth:`reset_at` restarts some environments (their next seed, or given seeds)
  while the others continue untouched; each environment has its own episode clock.
* An environment is truncated once its clock reaches ``max_steps``; it keeps running (and stays
  truncated) until it is reset with :meth:`reset_at`. It is never terminated.
* Continuous runs (``continuous=True``, the released trainer's one never-reset simulation):
  episodes are chunks of ``max_steps`` steps; :meth:`start_chunk` begins the next chunk of an
  environment without touching its traffic (truncation without reset), and the summary's
  per-period keys cover the current chunk (``metrics.batch_summary(since=...)``).
* Demand: ``densities`` gives each environment its own arrival rate [veh/lane/h].
* Observations are built only for the graphs in ``observe``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mivecc_env import metrics
from mivecc_env import signal_agents as signal_agents_mod
from mivecc_env.actions import checked_action
from mivecc_env.cloud_hold import HeldCloudCommands, decision_steps
from mivecc_env.config import ConfigError, MiVeCCConfig, from_overrides
from mivecc_env.sim import checks, cloud_view, edge_selection, graph_kernel, reward_kernel, sections
from mivecc_env.sim.core import Simulator, StepEvents
from mivecc_env.sim.state_graph import (
    StateGraphs,
    cloud_graphs,
    cloud_population,
    edge_graphs,
    population_limit_s,
)
from mivecc_env.sim.virtual_lane import VirtualLaneView

#: Names of the reward terms (the reward of a node is their sum).
REWARD_TERMS: tuple[str, ...] = ("reward_sv", "reward_velocity", "reward_collision")
GRAPHS = frozenset({"edge", "cloud"})
_SEED_HIGH = 2**63 - 1

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class BatchStep:
    """What :meth:`BatchedMiVeCCEnv.step` / ``reset`` / ``reset_at`` return (fresh arrays).

    Attributes:
        edge_obs: (B, n_edge, K_edge, K_edge, 3) float32 edge state graphs, ``None`` unless
            ``"edge"`` is observed.
        edge_mask: (B, n_edge, K_edge) float32, 1 for a real decision vehicle (or ``None``).
        cloud_obs: (B, K_cloud, K_cloud, 3) float32 cloud state graph, with
            ``cloud_graphs="per_lane"`` (B, n_lanes, K_cloud, K_cloud, 3): ``(B,
            *config.cloud_graph_shape)`` (or ``None``).
        cloud_mask: (B, *config.cloud_action_shape) float32 (or ``None``).
        edge_reward: (B, n_edge) float64, the sum of ``edge_terms``.
        cloud_reward: (B,) float64, the sum of ``cloud_terms``.
        edge_terms / cloud_terms: ``REWARD_TERMS`` -> (B, n_edge) / (B,) float64 (the edge
            ``reward_sv`` is 0 unless ``"edge"`` is observed: it needs the decision vehicles).
        terminated: (B,) bool (always False: continuous flow).
        truncated: (B,) bool, the environment's clock reached ``max_steps``.
        episode_steps: (B,) int64, steps of each environment since its own reset.
        signal_obs: (B, n_int, D) float32 signal-agent observations
            (:mod:`mivecc_env.signal_agents`), ``None`` unless ``signal_agents``.
        signal_reward: (B, n_int) float64 signal-agent rewards (or ``None``).
        signal_terms: ``SIGNAL_REWARD_TERMS`` -> (B, n_int) float64 (or ``None``).
    """

    edge_obs: Float32Array | None
    edge_mask: Float32Array | None
    cloud_obs: Float32Array | None
    cloud_mask: Float32Array | None
    edge_reward: FloatArray
    cloud_reward: FloatArray
    edge_terms: dict[str, FloatArray]
    cloud_terms: dict[str, FloatArray]
    terminated: BoolArray
    truncated: BoolArray
    episode_steps: NDArray[np.int64]
    signal_obs: Float32Array | None = None
    signal_reward: FloatArray | None = None
    signal_terms: dict[str, FloatArray] | None = None

    @property
    def done(self) -> BoolArray:
        """(B,) ``terminated | truncated``."""
        return self.terminated | self.truncated


class BatchedMiVeCCEnv:
    """B independent MiVeCC environments stepped together (see the module docstring).

    Args:
        config: a :class:`MiVeCCConfig`; keyword ``config_overrides`` replace its fields
            (``density`` is accepted for ``density_vplh``).
        batch_size: number of environments B >= 1.
        densities: (B,) demand of each environment [veh/lane/h] (default: the config's
            ``density_vplh`` for all).
        observe: which state graphs to build, a subset of ``{"edge", "cloud"}``; default by
            scheme: ``E``/``EE`` -> ``{"edge"}``, ``EEC`` -> ``{"edge", "cloud"}``.
        signal_agents: add the signal agents' arrays (``control="signalized"`` only; see
            :mod:`mivecc_env.signal_agents`).
        signal_reward: their reward, ``"queue"``, ``"pressure"`` or ``"throughput"``.
        continuous: episodes are chunks of ``max_steps`` steps of one continuing simulation
            (:meth:`start_chunk`); ``False`` (default): truncation at ``max_steps`` since the
            environment's reset.

    Raises:
        ConfigError: a bad config field, ``batch_size``, ``densities``, ``observe`` or
            ``signal_agents`` without ``control="signalized"``.
    """

    def __init__(
        self,
        config: MiVeCCConfig | None = None,
        batch_size: int = 1,
        *,
        densities: Sequence[float] | ArrayLike | None = None,
        observe: Sequence[str] | set[str] | frozenset[str] | None = None,
        signal_agents: bool = False,
        signal_reward: str = "queue",
        continuous: bool = False,
        **config_overrides: Any,
    ) -> None:
        if config is not None and not isinstance(config, MiVeCCConfig):
            raise ConfigError(f"config: must be a MiVeCCConfig, got {type(config).__name__}")
        if isinstance(batch_size, bool) or not isinstance(batch_size, int | np.integer) or (
            batch_size < 1
        ):
            raise ConfigError(f"batch_size: must be an integer >= 1, got {batch_size!r}")
        self.config = c = from_overrides(config, **config_overrides)
        self.batch_size = int(batch_size)
        if observe is None:
            observe = {"edge", "cloud"} if c.scheme == "EEC" else {"edge"}
        if isinstance(observe, str) or not set(observe) <= GRAPHS:
            raise ConfigError(f"observe: must be a subset of {sorted(GRAPHS)}, got {observe!r}")
        self.observe = frozenset(observe)
        self.signal_agents = signal_agents_mod.check_options(c, signal_agents, signal_reward)
        self.signal_reward = signal_reward
        try:
            self.sim = Simulator(c, batch_size=self.batch_size, seed=0, densities=densities)
        except ValueError as err:
            raise ConfigError(str(err)) from err
        self.n_edge = c.n_intersections
        self.k_edge, self.k_cloud = c.k_edge, c.k_cloud
        #: the cloud's observation and action shapes per environment (``config``'s)
        self.cloud_graph_shape, self.cloud_action_shape = c.cloud_graph_shape, c.cloud_action_shape
        # Accelerations are accepted up to this bound (float32 rounding of the box's edge).
        self._a_limit = c.a_max_mps2 + 1e-6
        self._seed_rngs = [np.random.default_rng() for _ in range(self.batch_size)]
        self._edge: StateGraphs | None = None
        self._cloud: StateGraphs | None = None
        self._area = np.zeros(0, dtype=np.int64)
        self._cloud_pop = np.zeros(0, dtype=bool)
        self._pop_limit = population_limit_s(self.sim.network, c.cloud_pick_population)
        self._cloud_reward_pop = self._cloud_pop
        self._v = np.zeros(0)
        self._started = False
        self._last: BatchStep | None = None
        self.continuous = bool(continuous)
        self._chunk_start = np.zeros(self.batch_size, dtype=np.int64)  # env step of its start
        self._chunk_counters = metrics.counters(self.sim)
        self._cloud_hold = HeldCloudCommands(self.sim.active.shape)

    # ------------------------------------------------------------------------------------
    @property
    def cloud_decides(self) -> BoolArray:
        """(B,) whether the cloud's action is used on each environment's next step
        (``config.cloud_period``, :mod:`mivecc_env.cloud_hold`; always true for 1)."""
        return decision_steps(self.sim.env_steps, self.config.cloud_period)

    @property
    def densities(self) -> FloatArray:
        """(B,) demand of each environment [veh/lane/h] (read-only view)."""
        d = self.sim.densities.view()
        d.flags.writeable = False
        return d

    @property
    def episode_steps(self) -> NDArray[np.int64]:
        """(B,) steps of each environment since its own last reset (continuous: since the
        start of its current chunk)."""
        return self.sim.env_steps - self._chunk_start

    @property
    def started(self) -> bool:
        """Whether :meth:`reset` has been called."""
        return self._started

    def summary(self) -> dict[str, FloatArray]:
        """Episode metrics so far: ``metrics.SUMMARY_KEYS`` -> (B,) float64 arrays.

        Read it before :meth:`reset_at` to keep the summary of an ended episode. Continuous
        runs: the per-period keys cover the current chunk (see the module docstring).
        """
        return metrics.batch_summary(self.sim, self._chunk_counters if self.continuous else None)

    def start_chunk(self, env_index: ArrayLike) -> BatchStep:
        """Continuous runs: begin the next chunk (episode) of some environments in place.

        Their vehicles, queues, arrival streams and clocks go on untouched; only the chunk's
        step count and the summary's per-period counters restart.

        Args:
            env_index: indices of the environments, or a (B,) bool mask.

        Returns:
            The current step of the batch with those environments no longer truncated.

        Raises:
            RuntimeError: not a continuous env, or ``reset`` not called.
        """
        if not self.continuous:
            raise RuntimeError("start_chunk: only for continuous=True (use reset_at)")
        if not self._started or self._last is None:
            raise RuntimeError("start_chunk: call reset() first")
        envs = self._env_indices(env_index)
        self._chunk_start[envs] = self.sim.env_steps[envs]
        now = metrics.counters(self.sim)
        for name, value in now.items():
            self._chunk_counters[name][envs] = value[envs]
        steps = self.episode_steps
        last = self._last
        self._last = dataclasses.replace(
            last, truncated=steps >= self.config.max_steps, episode_steps=steps
        )
        return self._last

    # ------------------------------------------------------------------------------------
    def reset(self, seed: int | Sequence[int] | None = None) -> BatchStep:
        """Restart every environment.

        Args:
            seed: an int ``s`` seeds environment ``b`` with ``s + b``; a sequence of B ints
                gives one seed per environment; ``None`` continues each environment's own
                seed sequence (fresh entropy before the first seeded reset).
        """
        envs = np.arange(self.batch_size)
        seeds = checks.check_seed(seed, self.batch_size)
        if seeds is not None:
            if isinstance(seeds, int):
                seeds = [seeds + b for b in range(self.batch_size)]
            self._seed_rngs = [np.random.default_rng(s) for s in seeds]
        self.sim.reset([self._next_sim_seed(b) for b in envs.tolist()])
        self._chunk_start[:] = 0
        self._chunk_counters = metrics.counters(self.sim)
        self._started = True
        return self._observe_and_pack(None)

    def reset_at(
        self, env_index: ArrayLike, seed: int | Sequence[int] | None = None
    ) -> BatchStep:
        """Restart some environments; the others continue untouched.

        Args:
            env_index: indices of the environments to restart, or a (B,) bool mask.
            seed: ``None``: each restarted environment takes the next seed of its own
                sequence; an int (one environment) or one int per restarted environment:
                reseeds their sequences (as ``reset(seed=...)`` does for a B = 1 env).

        Returns:
            The current step of the whole batch: the restarted environments with their first
            observations, rewards 0 and clock 0; the others as their last step returned them.
        """
        envs = self._env_indices(env_index)
        if not self._started:
            raise RuntimeError("reset_at: call reset() first")
        seeds = checks.check_seed(seed, envs.size)
        if isinstance(seeds, int):  # one int: for one restarted environment
            seeds = checks.check_seed([seeds], envs.size)
        if seeds is not None:
            for b, s in zip(envs.tolist(), seeds, strict=True):
                self._seed_rngs[b] = np.random.default_rng(s)
        last = self._last
        self.sim.reset_at(envs, [self._next_sim_seed(b) for b in envs.tolist()])
        self._chunk_start[envs] = 0
        for name, value in metrics.counters(self.sim).items():
            self._chunk_counters[name][envs] = value[envs]
        out = self._observe_and_pack(None)
        if last is not None:
            # The environments that go on keep the rewards of their last step.
            keep = np.ones(self.batch_size, dtype=bool)
            keep[envs] = False
            for new, old in ((out.edge_terms, last.edge_terms), (out.cloud_terms, last.cloud_terms),
                             ({"r": out.edge_reward}, {"r": last.edge_reward}),
                             ({"r": out.cloud_reward}, {"r": last.cloud_reward}),
                             (out.signal_terms or {}, last.signal_terms or {}),
                             ({"r": out.signal_reward} if self.signal_agents else {},
                              {"r": last.signal_reward})):
                for k in new:
                    new[k][keep] = old[k][keep]
        return out

    def step(
        self, edge_action: ArrayLike | None = None, cloud_action: ArrayLike | None = None,
        signal_action: ArrayLike | None = None, raw_edge: ArrayLike | None = None,
    ) -> BatchStep:
        """Apply the coordinators' accelerations and advance every environment one step.

        Args:
            edge_action: (B, n_edge, K_edge) accelerations [m/s^2] of each edge node's columns,
                or ``None`` (no edge action: the on-board rules decide).
            cloud_action: (B, K_cloud) accelerations [m/s^2] of the cloud node's columns
                (``(B, n_lanes, K_cloud)`` with ``cloud_graphs="per_lane"``: ``(B,
                *cloud_action_shape)``), or ``None``. Actions of padded columns are ignored.
                Under scheme ``E`` both are ignored, under ``EE`` the cloud action is.
                With ``cloud_period = n > 1`` the cloud action is used only on the
                environments' decision steps (:attr:`cloud_decides`) and then held by the
                vehicles it commands (:mod:`mivecc_env.cloud_hold`); on other steps it is
                ignored.
            signal_action: (B, n_int) integer phase each signal agent wants green (0
                east-west, 1 north-south), -1 where ``signal_controller`` decides; ``None``:
                it decides everywhere. Needs ``signal_agents=True``.
            raw_edge: (B,) bool or one bool for all: in those environments the edge action
                replaces the rule's action of its decision vehicles unmodified (no SV gate, no
                veto, no max; the released trainer's exploration on every other step, see
                ``end_node.fuse``); ``None``: the normal fusion everywhere.

        Raises:
            RuntimeError: ``reset`` has not been called.
            ValueError: an action of the wrong shape, NaN/inf in a real column, or outside
                ``[-a_max, a_max]`` (the message names the argument; rule:
                :mod:`mivecc_env.actions`, which also accepts torch tensors); a signal action
                without ``signal_agents``, of the wrong shape, not integer or out of range.
        """
        edge = self._checked(edge_action, "edge_action", (self.batch_size, self.n_edge,
                                                          self.k_edge))
        cloud = self._checked(cloud_action, "cloud_action",
                              (self.batch_size, *self.cloud_action_shape))
        signal = None
        if signal_action is not None:
            if not self.signal_agents:
                raise ValueError("signal_action: needs signal_agents=True")
            signal = signal_agents_mod.check_action(signal_action,
                                                    (self.batch_size, self.n_edge))
        raw = None
        if raw_edge is not None:
            raw = np.asarray(raw_edge)
            if raw.shape not in ((), (1,), (self.batch_size,)):
                raise ValueError(f"raw_edge: expected one bool or {self.batch_size} bools, "
                                 f"got shape {raw.shape}")
            if raw.dtype != bool:
                raise ValueError(f"raw_edge: expected bools, got dtype {raw.dtype}")
            raw = np.broadcast_to(raw, (self.batch_size,))
        return self.step_commands(edge, cloud, signal, raw)

    def step_vehicles(self, accel: ArrayLike) -> BatchStep:
        """Advance every environment one step with an acceleration per vehicle slot, executed
        unmodified (CoMADDPG's vehicle agents: :mod:`mivecc_env.vehicle_agents`).

        Args:
            accel: (B, capacity) acceleration [m/s^2] of each vehicle slot
                (``vehicle_agents.vehicle_commands``), NaN where the end-node rules decide.
                Only the velocity bounds apply to the others (no rule, no veto).

        Raises:
            RuntimeError: ``reset`` has not been called.
            ValueError: not scheme ``EE`` / ``EEC`` under unsignalized control without the
                safety shield (the command travels as the edge action), one of the released
                code's overrides on (``header_rule``, ``sections``, ``speed_reset``), the wrong
                shape, +-inf, or a value outside ``[-a_max, a_max]``.
        """
        c = self.config
        if c.scheme == "E" or c.control != "unsignalized" or c.safety_shield:
            raise ValueError("step_vehicles: needs scheme 'EE' or 'EEC', control='unsignalized' "
                             f"and no safety_shield, got scheme={c.scheme!r}, "
                             f"control={c.control!r}, safety_shield={c.safety_shield!r}")
        overriding = [f for f in ("header_rule", "sections", "speed_reset") if getattr(c, f)]
        if overriding:  # the released code's overrides would replace the vehicles' actions
            raise ValueError(f"step_vehicles: needs {', '.join(overriding)} off (they override "
                             "every action; e.g. model='paper'), got them on")
        if not self._started:
            raise RuntimeError("step: call reset() first")
        sim = self.sim
        cmd = checks.check_accel("accel", accel, sim.active.shape)
        if np.any(np.abs(cmd) > self._a_limit):  # NaN compares False
            raise ValueError(f"accel: must be within [-{c.a_max_mps2}, {c.a_max_mps2}] m/s^2 "
                             "(or NaN: the rules decide)")
        events = sim.step(cmd.astype(np.float64, copy=False), None,
                          raw_edge=np.ones(self.batch_size, dtype=bool))
        return self._observe_and_pack(events)

    # ------------------------------------------------------------------------------------
    # for adapters
    def step_commands(
        self, edge_action: FloatArray | None, cloud_action: FloatArray | None,
        signal_action: NDArray[np.int64] | None = None,
        raw_edge: BoolArray | None = None,
    ) -> BatchStep:
        """:meth:`step` without validation; NaN in an action means "no action" for that column.

        For adapters that validated the actions already (the PettingZoo env sends NaN for the
        agents left out of its action dict).
        """
        if not self._started:
            raise RuntimeError("step: call reset() first")
        sim, scheme = self.sim, self.config.scheme
        # An action the scheme ignores is not mapped; one it uses needs its graph's columns.
        edge_cmd = cloud_cmd = None
        if edge_action is not None and scheme != "E":
            if self._edge is None:
                raise RuntimeError("step: edge_action given but 'edge' is not observed")
            edge_cmd = self._commands(self._edge, edge_action)
        if cloud_action is not None and scheme == "EEC":
            if self._cloud is None:
                raise RuntimeError("step: cloud_action given but 'cloud' is not observed")
            cloud_cmd = self._commands(
                self._cloud, cloud_action.reshape(len(cloud_action), -1, self.k_cloud))
        if self.config.cloud_period > 1 and scheme == "EEC":
            view = sim.view
            cloud_cmd = self._cloud_hold.commands(
                cloud_cmd, self.cloud_decides, sim.vid, view.vehicle[self._cloud_pop])
        events = sim.step(edge_cmd, cloud_cmd, signal_phase=signal_action, raw_edge=raw_edge)
        return self._observe_and_pack(events)

    def _commands(self, graphs: StateGraphs, action: FloatArray) -> FloatArray:
        """(B, capacity) per-slot command (NaN where none) from per-column actions."""
        b, capacity = self.sim.active.shape
        # One spare element at the end takes the padded columns (slot -1) in a single scatter.
        flat = np.full(b * capacity + 1, np.nan)
        flat[graphs.slot] = action
        return flat[:-1].reshape(b, capacity)

    # ------------------------------------------------------------------------------------
    def _observe_and_pack(self, events: StepEvents | None) -> BatchStep:
        """Build the observed graphs, the rewards (``None`` events: zero) and the flags."""
        sim, c, b = self.sim, self.config, self.batch_size
        view = sim.view
        v = sim.v.ravel()[view.vehicle]
        a = sim.a.ravel()[view.vehicle]
        # the section's controlled part under sections=True (released code)
        net = sim.network
        if (graph_kernel.HAVE_NUMBA and not c.sections and self._pop_limit is not None
                and view.lane.dtype == np.int64 and view.s.dtype == np.float64):
            # both in one compiled pass (the same values as the two calls below)
            area, self._cloud_pop = graph_kernel.control_area_before(
                view.lane, view.s, net.lane_centres_s, net.lane_intersections,
                net.control_radius_m, net.segment_length_m, self._pop_limit)
        else:
            area = sections.control_area(net, c, view.lane, view.s)
            # The cloud picks and is rewarded over one population (cloud_pick_population).
            self._cloud_pop = cloud_population(net, view, c.cloud_pick_population,
                                               self._pop_limit)
        self._area = area
        self._cloud_reward_pop = cloud_view.reward_population(
            sim.network, c, view, self._cloud_pop, sim.prev_positions)
        self._v = v
        self._edge = self._cloud = None
        if "edge" in self.observe:
            key = edge_selection.edge_priority(sim.safety.sv, view.env, sim.selection_rngs, c,
                                                sim.step_count)
            self._edge = edge_graphs(sim.network, view, key, v, a, b, c, area)
        if "cloud" in self.observe:
            cview = cloud_view.cloud_virtual_lanes(sim.network, c, view, sim.active, sim.lane,
                                                   sim.s)  # the same view by default
            # the density indicator: computed in the cloud selection (config.di_n)
            self._cloud = cloud_graphs(sim.network, cview, None, v, a, b, c, self._cloud_pop)
        edge_terms, cloud_terms, edge_reward, cloud_reward = self._reward_terms(events)
        steps = self.episode_steps
        edge, cloud = self._edge, self._cloud
        signal_obs = signal_reward = signal_terms = None
        if self.signal_agents:
            signal_obs, signal_reward, signal_terms = signal_agents_mod.observe(
                sim, self.signal_reward, events is not None)
        self._last = BatchStep(
            edge_obs=None if edge is None else edge.obs,
            edge_mask=None if edge is None else edge.mask,
            cloud_obs=None if cloud is None else cloud.obs.reshape(b, *self.cloud_graph_shape),
            cloud_mask=None if cloud is None else cloud.mask.reshape(
                b, *self.cloud_action_shape),
            edge_reward=edge_reward,
            cloud_reward=cloud_reward,
            edge_terms=edge_terms,
            cloud_terms=cloud_terms,
            terminated=np.zeros(b, dtype=bool),
            truncated=steps >= c.max_steps,
            episode_steps=steps,
            signal_obs=signal_obs,
            signal_reward=signal_reward,
            signal_terms=signal_terms,
        )
        return self._last

    def _reward_terms(
        self, events: StepEvents | None
    ) -> tuple[dict[str, FloatArray], dict[str, FloatArray], FloatArray, FloatArray]:
        """Edge (B, n_edge) and cloud (B,) reward terms of the current state and events, and
        the rewards (their sums)."""
        c, sim, b, n = self.config, self.sim, self.batch_size, self.n_edge
        if events is None:
            edge = {k: np.zeros((b, n)) for k in REWARD_TERMS}
            cloud = {k: np.zeros(b) for k in REWARD_TERMS}
            return edge, cloud, _total(edge), _total(cloud)
        view = sim.view
        if reward_kernel.HAVE_NUMBA and c.edge_reward_scope != "decisions":
            # One compiled call for the terms and sums below (bit-identical); only the SV sums
            # of the decisions stay numpy's (its pairwise summation order).
            sv_sum = vi = None
            if self._edge is not None:
                vi = self._edge.view_index.reshape(b * n, -1)
                # padded columns (-1) add an exact 0.0 (no copy of every vehicle's SV)
                sv = sim.safety.sv
                picked = sv[vi] if sv.size else np.zeros(vi.shape)
                picked[vi < 0] = 0.0
                sv_sum = picked.sum(axis=1)
            edge_rows, cloud_rows = reward_kernel.terms(
                view.env, self._area, self._cloud_reward_pop, self._v, c.reward_v_ref_mps, b, n,
                events.collided_env, events.collided_area, events.collided_vehicles,
                c.collision_penalty, sv_sum, vi, c.reward_sv_weight)
            edge_rows = edge_rows.reshape(4, b, n)
            return (dict(zip(REWARD_TERMS, edge_rows[:3], strict=True)),
                    dict(zip(REWARD_TERMS, cloud_rows[:3], strict=True)),
                    edge_rows[3], cloud_rows[3])
        count, vel_sum, env_count, env_vel = self._node_sums(view)
        count, vel_sum = count.reshape(b, n), vel_sum.reshape(b, n)
        hit = events.collided_area >= 0
        hits = np.bincount(events.collided_env[hit] * n + events.collided_area[hit],
                           minlength=b * n).reshape(b, n)
        # Empty areas have zero sums, so dividing by max(count, 1) gives their 0.
        edge = {
            "reward_sv": np.zeros((b, n)),  # needs the edge decisions: 0 unless observed
            "reward_velocity": vel_sum / np.maximum(count, 1),
            "reward_collision": -c.collision_penalty * hits,
        }
        if self._edge is not None:
            vi = self._edge.view_index
            # Column -1 (padding) picks the appended 0, so padded columns add nothing.
            sv_sum = np.append(sim.safety.sv, 0.0)[vi].sum(axis=2)
            n_dec = np.maximum((vi >= 0).sum(axis=2), 1)
            edge["reward_sv"] = c.reward_sv_weight * (sv_sum / n_dec)
            if c.edge_reward_scope == "decisions":  # released trainer: the decision vehicles
                dv = np.append(self._v - c.reward_v_ref_mps, 0.0)
                edge["reward_velocity"] = dv[vi].sum(axis=2) / n_dec
        cloud = {
            "reward_sv": np.zeros(b),
            "reward_velocity": env_vel / np.maximum(env_count, 1),
            "reward_collision": -c.collision_penalty * events.collided_vehicles.astype(np.float64),
        }
        return edge, cloud, _total(edge), _total(cloud)

    def _node_sums(self, view: VirtualLaneView) -> tuple[NDArray[np.int64], FloatArray,
                                                          NDArray[np.int64], FloatArray]:
        """Vehicles and sums of ``v - reward_v_ref_mps`` per edge node (B * n_edge,) and over
        the cloud population per environment (B,) (compiled: :mod:`..sim.reward_kernel`)."""
        b, n, v_ref = self.batch_size, self.n_edge, self.config.reward_v_ref_mps
        area, pop = self._area, self._cloud_reward_pop
        if reward_kernel.HAVE_NUMBA:
            return reward_kernel.node_sums(view.env, area, pop, self._v, v_ref, b, n)
        inside = area >= 0
        dv = self._v - v_ref
        node = view.env[inside] * n + area[inside]
        env_pop = view.env[pop]
        return (np.bincount(node, minlength=b * n), np.bincount(node, dv[inside], minlength=b * n),
                np.bincount(env_pop, minlength=b), np.bincount(env_pop, dv[pop], minlength=b))

    # ------------------------------------------------------------------------------------
    def _next_sim_seed(self, b: int) -> int:
        return int(self._seed_rngs[b].integers(0, _SEED_HIGH))

    def _env_indices(self, env_index: ArrayLike) -> NDArray[np.int64]:
        """Sorted distinct indices of ``env_index`` (indices or a (B,) bool mask)."""
        return np.sort(checks.check_env_indices(env_index, self.batch_size, mask_ok=True))

    def _checked(
        self, action: ArrayLike | None, name: str, shape: tuple[int, ...]
    ) -> FloatArray | None:
        """``action`` as a float64 array of ``shape`` (rule: :mod:`mivecc_env.actions`).

        The masks of the last observation tell the padded columns (edge masks for
        ``edge_action``, the cloud mask for ``cloud_action``).
        """
        if action is None:
            return None
        return checked_action(action, name, shape, self.config.a_max_mps2,
                              self._action_mask(name, shape))

    def _action_mask(self, name: str, shape: tuple[int, ...]) -> NDArray[Any] | None:
        """Real-column mask of the last observation for ``name``'s action, or ``None``."""
        last = self._last
        if last is None:
            return None
        mask = last.cloud_mask if name == "cloud_action" else last.edge_mask
        return mask if mask is not None and mask.shape == shape else None


def _total(terms: dict[str, FloatArray]) -> FloatArray:
    """Reward = sum of the terms (in ``REWARD_TERMS`` order)."""
    sv, vel, col = (terms[k] for k in REWARD_TERMS)
    return sv + vel + col
