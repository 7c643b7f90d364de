"""Signal agents: one ``signal_i`` per intersection chooses the phase (``control="signalized"``).

Opt in with ``signal_agents=True`` on :class:`mivecc_env.batched.BatchedMiVeCCEnv` or the
PettingZoo env (``mivecc_v0.parallel_env(control="signalized", signal_agents=True)``).

Action: ``Discrete(2)``, the phase the agent wants green (0 east-west, 1 north-south). The
phase state machine (:mod:`mivecc_env.sim.signal_control`) enforces the minimum green, the
yellow and the all-red: asking for the other phase ends the current green only once it has
lasted ``signal_min_green_s``, and the other phase turns green after the yellow and all-red.
An agent that sends no action leaves its intersection to ``signal_controller`` (fixed-time by
default).

Observation: float32 ``(15,)`` per intersection, :data:`OBS_FEATURES` in order: for each
approach (lane heading east, west, north, south) the vehicles within ``control_radius_m`` before
the centre, those of them slower than 0.5 m/s (queued) and their mean velocity [m/s]; then the
current phase (0 / 1), its stage (0 green, 1 yellow, 2 all-red) and the seconds spent in that
stage. Bounds: :func:`observation_bounds`.

Reward per intersection: the term named by ``signal_reward`` (``"queue"``: -(queued
vehicles), ``"pressure"``: -|upstream - downstream vehicles|, ``"throughput"``: the vehicles
that passed the intersection's centre in the step); every term is reported
(:data:`SIGNAL_REWARD_TERMS`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.network import HEADINGS
from mivecc_env.sim.signal_control import (
    APPROACH_FEATURES,
    N_PHASES,
    PHASE_FEATURES,
    signal_observation,
)

#: Names of the signal agents' reward terms (in the infos of every signal agent).
SIGNAL_REWARD_TERMS: tuple[str, ...] = ("reward_queue", "reward_pressure", "reward_throughput")
#: Allowed ``signal_reward`` values -> the term used as the reward.
SIGNAL_REWARDS = {"queue": "reward_queue", "pressure": "reward_pressure",
                  "throughput": "reward_throughput"}
#: Feature names of the observation, in order.
OBS_FEATURES: tuple[str, ...] = (
    *(f"{h}_{f}" for h in HEADINGS for f in APPROACH_FEATURES), *PHASE_FEATURES
)
OBS_DIM = len(OBS_FEATURES)
SIGNAL_GROUP = "signal"

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]
IntArray = NDArray[np.int64]


def signal_agent(index: int) -> str:
    """Name of the signal agent of intersection ``index``."""
    return f"{SIGNAL_GROUP}_{index}"


def check_options(config: MiVeCCConfig, signal_agents: Any, signal_reward: Any) -> bool:
    """Validate the opt-in flag and the reward choice; return ``signal_agents`` as a bool."""
    if not isinstance(signal_agents, bool | np.bool_):
        raise ConfigError(f"signal_agents: must be True or False, got {signal_agents!r}")
    if signal_agents and config.control != "signalized":
        raise ConfigError("signal_agents: only with control='signalized', got control="
                          f"{config.control!r}")
    if signal_reward not in SIGNAL_REWARDS:
        raise ConfigError(f"signal_reward: must be one of {sorted(SIGNAL_REWARDS)}, "
                          f"got {signal_reward!r}")
    return bool(signal_agents)


def observation_bounds(config: MiVeCCConfig) -> tuple[Float32Array, Float32Array]:
    """(low, high) of the observation, each ``(OBS_DIM,)`` float32.

    Vehicle counts on one approach are at most ``floor(control_radius_m / vehicle_length_m)
    + 1`` (closer vehicles collide); velocities are in ``[0, v_max_mps]`` under signals; the
    phase is 0 / 1, the stage 0 / 1 / 2; the stage's elapsed time is at most the initial
    green (``signal_green_s``) plus the episode (``max_steps * dt_s``).
    """
    count = np.floor(config.control_radius_m / config.vehicle_length_m) + 1
    per_approach = [count, count, config.v_max_mps]
    elapsed = config.signal_green_s + config.max_steps * config.dt_s
    high = np.array([*per_approach * len(HEADINGS), N_PHASES - 1, 2, elapsed], dtype=np.float32)
    return np.zeros(OBS_DIM, dtype=np.float32), high


def observe(sim: Simulator, reward: str, with_rewards: bool
            ) -> tuple[Float32Array, FloatArray, dict[str, FloatArray]]:
    """Signal observations (B, n_int, OBS_DIM) float32, rewards and terms (B, n_int) float64.

    ``with_rewards=False`` (at reset) gives zero rewards and terms, as the coordinators get.
    """
    view = sim.view
    v = sim.v.ravel()[view.vehicle]
    obs, terms = signal_observation(sim.network, sim.config, view, view.s, v,
                                    sim.signal_phases, sim.prev_positions)
    if not with_rewards:
        terms = {k: np.zeros_like(t) for k, t in terms.items()}
    terms = {k: terms[k].astype(np.float64) for k in SIGNAL_REWARD_TERMS}
    return obs.astype(np.float32), terms[SIGNAL_REWARDS[reward]].copy(), terms


def check_action(action: Any, shape: tuple[int, int], name: str = "signal_action") -> IntArray:
    """``(B, n_int)`` phases (-1: the controller decides) as int64, or ``ValueError``."""
    expected = f"expected shape {shape} of integers in {{-1, 0, 1}} (-1: controller decides)"
    arr = np.asarray(action)
    if arr.shape != shape:
        raise ValueError(f"{name}: {expected}, got shape {arr.shape}")
    if arr.dtype.kind not in "iu":
        raise ValueError(f"{name}: {expected}, got dtype {arr.dtype}")
    if arr.size and (arr.min() < -1 or arr.max() > N_PHASES - 1):
        raise ValueError(f"{name}: {expected}, got range [{arr.min()}, {arr.max()}]")
    return arr.astype(np.int64)


def check_agent_action(agent: str, action: Any) -> int:
    """One agent's ``Discrete(2)`` action as an int, or ``ValueError`` naming the agent."""
    arr = np.asarray(action) if not isinstance(action, str | bytes) else None
    if arr is None or arr.shape != () or arr.dtype.kind not in "iu":
        raise ValueError(f"actions[{agent!r}]: expected an integer phase in [0, "
                         f"{N_PHASES - 1}] (Discrete({N_PHASES})), got {action!r}")
    value = int(arr)
    if not 0 <= value < N_PHASES:
        raise ValueError(f"actions[{agent!r}]: expected an integer phase in [0, "
                         f"{N_PHASES - 1}] (Discrete({N_PHASES})), got {value}")
    return value
