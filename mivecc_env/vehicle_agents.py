"""Vehicles as agents: each vehicle's view of its virtual lane and its raw acceleration.

The interface of CoMADDPG (:mod:`mivecc_agents.comaddpg`, Wu et al. 2020), where every vehicle
inside an intersection's control area is an agent: it observes itself and its ``K - 1`` nearest
reference vehicles on its virtual lane (one column of an edge state graph, the same features and
scaling: :mod:`mivecc_env.sim.state_graph`) and sets its own acceleration, which the simulator
executes unmodified (``Simulator.step(raw_edge=...)``: no end-node rule, no veto; the velocity
bounds still hold). Vehicles outside every control area follow the end-node rules.

:func:`observe_vehicles` lists the agents of a simulator's current state;
:func:`vehicle_accelerations` asks a policy for their accelerations (one call per environment)
and :func:`vehicle_commands` turns them into the simulator's per-slot command;
:func:`follow` finds each agent again after a step and :func:`vehicle_rewards` is CoMADDPG's
per-vehicle reward (one formula for its trainer and the PettingZoo view,
:mod:`mivecc_env.vehicle_env`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import sections
from mivecc_env.sim.core import Simulator, StepEvents
from mivecc_env.sim.state_graph import build_graphs

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: The config fields under which vehicles are agents (``BatchedMiVeCCEnv.step_vehicles``):
#: unsignalized control, the vehicles' command carried as the edge action (scheme ``EE``), no
#: shield, the default model (the released one's overrides would replace the vehicles' actions).
VEHICLE_AGENT_FIELDS: dict[str, object] = {"control": "unsignalized", "scheme": "EE",
                                           "safety_shield": False, "model": "paper"}


@dataclass(frozen=True)
class VehicleAgents:
    """The vehicle agents of a batch of environments at one step (n agents, environment order).

    Attributes:
        obs: (n, K, 3) float32: row 0 the vehicle (signed distance to its next conflict point,
            velocity, acceleration), rows ``1..K-1`` its references nearest first (position
            relative to it on the virtual lane, velocity, acceleration), zero rows where fewer
            exist; every feature in ``[-1, 1]`` (:mod:`mivecc_env.sim.state_graph`).
        env: (n,) environment of each agent.
        slot: (n,) flat vehicle slot ``env * capacity + slot`` (the capacity of this step).
        vid: (n,) vehicle id (unique within its environment).
        ref_agent: (n, K-1) agent index of each reference row, -1 where the row is padding or
            shows a vehicle outside every control area (a crossing vehicle projected into
            this area from just outside its own).
        velocity: (n,) velocity [m/s].
        sv: (n,) safety value (``Simulator.safety``).
        capacity: the simulator's vehicle slots per environment at this step.
    """

    obs: NDArray[np.float32]
    env: IntArray
    slot: IntArray
    vid: IntArray
    ref_agent: IntArray
    velocity: FloatArray
    sv: FloatArray
    capacity: int

    def __len__(self) -> int:
        return int(self.env.size)

    def rows_of(self, env: int) -> slice:
        """The agents of environment ``env`` (a contiguous block: agents are in env order)."""
        lo, hi = np.searchsorted(self.env, [env, env + 1])
        return slice(int(lo), int(hi))


def observe_vehicles(sim: Simulator, k: int) -> VehicleAgents:
    """The agents of ``sim``'s current state: every vehicle inside a control area.

    Args:
        sim: the simulator (any batch size).
        k: rows of an observation: the vehicle and its ``k - 1`` references (at least 2).
    """
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 2:
        raise ValueError(f"k: must be an integer >= 2, got {k!r}")
    c, net, view = sim.config, sim.network, sim.view
    area = sections.control_area(net, c, view.lane, view.s)
    decision = np.flatnonzero(area >= 0)
    decision = decision[np.argsort(view.env[decision], kind="stable")]
    d = decision.size
    lane = view.lane[decision]
    which = np.argmax(net.lane_intersections[lane] == area[decision][:, None], axis=1)
    centre = net.lane_centres_s[lane, which]
    flat = view.vehicle
    velocity = sim.v.ravel()[flat]
    # the agents packed k to a graph, one per column: column j of a graph is an agent's view
    n_graphs = max(-(-d // k), 1)
    refs = np.empty((d, k - 1), dtype=np.int64)
    graphs = build_graphs(net, view, velocity, sim.a.ravel()[flat], decision,
                          np.arange(d) // k, np.arange(d) % k, n_graphs, 1, k,
                          2.0 * c.control_radius_m, c, centre, c.control_radius_m,
                          references=refs)
    # (agent, row, channel); the reshape of the transposed graphs makes a contiguous copy
    obs = graphs.obs[0].transpose(0, 2, 1, 3).reshape(n_graphs * k, k, 3)[:d]
    agent_of_view = np.full(view.env.size + 1, -1, dtype=np.int64)
    agent_of_view[decision] = np.arange(d)
    ref_agent = agent_of_view[refs]  # -1 (padding) reads the spare entry
    return VehicleAgents(
        obs=obs, env=view.env[decision].astype(np.int64), slot=flat[decision].astype(np.int64),
        vid=sim.vid.ravel()[flat[decision]].astype(np.int64), ref_agent=ref_agent,
        velocity=velocity[decision], sv=sim.safety.sv[decision], capacity=sim.capacity,
    )


def vehicle_commands(agents: VehicleAgents, accel: FloatArray, batch_size: int) -> FloatArray:
    """(B, capacity) per-slot acceleration [m/s^2] of the agents, NaN for every other slot
    (those follow the end-node rules); ``accel`` is (n,) in agent order."""
    accel = np.asarray(accel, dtype=np.float64)
    if accel.shape != (len(agents),):
        raise ValueError(f"accel: expected shape ({len(agents)},) (one per agent), got "
                         f"{accel.shape}")
    flat = np.full(batch_size * agents.capacity, np.nan)
    flat[agents.slot] = accel
    return flat.reshape(batch_size, agents.capacity)


def vehicle_accelerations(policy: Callable[[NDArray[np.float32]], ArrayLike],
                          agents: VehicleAgents, batch_size: int, a_max: float) -> FloatArray:
    """(n,) accelerations of the agents, clipped to ``a_max``: one policy call per environment
    on its own rows (so no environment's actions depend on the batch it runs in)."""
    out = np.zeros(len(agents))
    for b in range(batch_size):
        rows = agents.rows_of(b)
        if rows.stop > rows.start:
            a = np.asarray(policy(agents.obs[rows]), dtype=np.float64)
            if a.shape != (rows.stop - rows.start,):
                raise ValueError(f"policy returned shape {a.shape}, expected "
                                 f"({rows.stop - rows.start},)")
            if not np.isfinite(a).all():
                raise ValueError("policy returned NaN or inf accelerations")
            out[rows] = a
    return np.clip(out, -a_max, a_max)


def follow(agents: VehicleAgents, nxt: VehicleAgents) -> tuple[NDArray[np.bool_], IntArray]:
    """Where each agent of ``agents`` is among ``nxt`` (the same environment and vehicle id):
    (n,) whether it is an agent again, and (n,) its index in ``nxt`` (0 where not)."""
    key = agents.env * (1 << 32) + agents.vid
    next_key = nxt.env * (1 << 32) + nxt.vid
    found, j = np.zeros(len(agents), dtype=bool), np.zeros(len(agents), dtype=np.int64)
    if next_key.size:
        order = np.argsort(next_key, kind="stable")
        cand = order[np.minimum(np.searchsorted(next_key[order], key), next_key.size - 1)]
        found = next_key[cand] == key
        j = np.where(found, cand, 0)
    return found, j


def vehicle_rewards(agents: VehicleAgents, action: FloatArray, nxt: VehicleAgents,
                    events: StepEvents, config: MiVeCCConfig, collision_penalty: float,
                    safety_weight: float) -> FloatArray:
    """(n,) reward of each agent for the step from ``agents`` (accelerations ``action``
    [m/s^2]) to ``nxt``: ``(v' - v_max) / (v_max - v_floor)`` (0 at full speed, -1 at the
    floor; ``v'`` the velocity its action gives) ``+ safety_weight * min(SV', 0) / 20`` (its
    safety value after the step, where it is still an agent) ``- collision_penalty`` if it
    collided in the step."""
    lo, hi = config.velocity_floor_mps, config.v_max_mps
    v_new = np.clip(agents.velocity + action * config.dt_s, lo, hi)
    reward = (v_new - hi) / (hi - lo)
    reward -= collision_penalty * np.isin(agents.slot, events.collided_slot)
    found, j = follow(agents, nxt)
    if nxt.sv.size:
        reward += np.where(found, safety_weight * np.minimum(nxt.sv[j], 0.0) / 20.0, 0.0)
    return reward
