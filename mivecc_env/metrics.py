"""Traffic-efficiency metrics of a simulation: per-episode summaries and the upper bound.

* average travel velocity: per exited vehicle, path length over trip time, the trip counted
  from its arrival at the entry queue (``avg_travel_velocity_mps``) or from its entry into the
  network (``avg_travel_velocity_no_wait_mps``), averaged over the exited vehicles;
* its theoretical upper bound: enter at ``v_init``, accelerate at ``a_max`` to ``v_max``,
  cruise to the exit (no waiting);
* mean speed in the network (over all vehicle-steps), throughput (exited vehicles, and per
  hour), collisions (events and vehicles removed), entry backlog (queued vehicles), mean trip
  and waiting times, and the accounting terms;
* ``released_check_collisions``: the collision count of the released code's own, lenient
  check, per vehicle it flags (``mivecc_env.sim.released_check``), beside this project's
  strict event count ``collisions``;
* the released code's velocity (``released_velocity_mps``): path length from the network entry
  to 5 m past the last intersection centre of the lane (455 m on 3x3) over the mean passing
  time to that mark, no entry wait (``mivecc_env.sim.passing``: ``sum(length) / sum(time)``,
  i.e. mean length / mean time, not the mean of per-vehicle velocities; 0 before any vehicle
  has passed), and ``released_passed``, the number of vehicles that passed the mark;
* near-miss measures (``mivecc_env.sim.near_miss`` defines them): minimum and 1st-percentile
  time to collision on the virtual lanes (``min_ttc_s``, ``ttc_p1_s``), post-encroachment time
  at the conflict points (``min_pet_s``, ``pet_under_1s``, ``pet_samples``) and the minimum
  centre distance between two vehicles (``min_distance_m``).

A minimum without samples (no TTC or PET sample, never two vehicles at once) is ``inf``, the
minimum of nothing; no summary value is ever NaN (the summaries travel in the environments'
infos, and NaN != NaN would break their equality checks, e.g. PettingZoo's seed test).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

from mivecc_env import summary_kernel
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import near_miss
from mivecc_env.sim.checks import check_env_index

if TYPE_CHECKING:
    from mivecc_env.sim.core import Simulator

#: Keys of :func:`episode_summary`, in a fixed order (all values are floats).
SUMMARY_KEYS: tuple[str, ...] = (
    "avg_travel_velocity_mps", "avg_travel_velocity_no_wait_mps", "upper_bound_mps",
    "mean_speed_mps", "throughput", "throughput_vph", "collisions", "collided_vehicles",
    "released_check_collisions", "backlog", "in_network", "arrived", "mean_trip_time_s",
    "mean_wait_time_s", "sim_time_s",
    "released_velocity_mps", "released_passed",
    "min_ttc_s", "ttc_p1_s", "min_pet_s", "pet_under_1s", "pet_samples", "min_distance_m",
)

#: The keys of :data:`SUMMARY_KEYS` that are ``inf`` when there is no sample.
INF_WHEN_NO_DATA: tuple[str, ...] = ("min_ttc_s", "ttc_p1_s", "min_pet_s", "min_distance_m")


def min_travel_time_s(config: MiVeCCConfig, path_length_m: float | np.ndarray) -> np.ndarray:
    """Shortest possible trip [s]: from ``v_init`` accelerate at ``a_max`` to ``v_max``, cruise."""
    v0, v1, a = config.v_init_mps, config.v_max_mps, config.a_max_mps2
    length = np.asarray(path_length_m, dtype=np.float64)
    t_acc = (v1 - v0) / a
    d_acc = (v1 * v1 - v0 * v0) / (2.0 * a)
    # A path shorter than the acceleration distance never reaches v_max.
    short = length < d_acc
    t_short = (-v0 + np.sqrt(v0 * v0 + 2.0 * a * np.minimum(length, d_acc))) / a
    return np.where(short, t_short, t_acc + (length - d_acc) / v1)


@functools.lru_cache(maxsize=64)
def upper_bound_velocity_mps(config: MiVeCCConfig) -> float:
    """Theoretical upper bound of the average travel velocity [m/s].

    Every entry lane has the same demand, so the bound is the mean over through lanes of
    ``path_length / min_travel_time``.
    """
    seg = config.segment_length_m
    lengths = np.array([(config.cols + 1) * seg] * (2 * config.rows)
                       + [(config.rows + 1) * seg] * (2 * config.cols))
    return float(np.mean(lengths / min_travel_time_s(config, lengths)))


_last_bound: list = [None, 0.0]  # (config, its upper bound): configs are immutable


def _upper_bound_of(config: MiVeCCConfig) -> float:
    """:func:`upper_bound_velocity_mps` with a one-entry identity memo (hashing a config, as
    its cache does, costs more than the rest of a per-step summary's scalars)."""
    if _last_bound[0] is not config:
        _last_bound[:] = [config, upper_bound_velocity_mps(config)]
    return _last_bound[1]


#: Simulator counters behind the summary's per-period keys (:func:`counters`).
COUNTERS: tuple[str, ...] = (
    "exited", "collision_events", "collided", "released_flagged", "sum_travel_velocity",
    "sum_travel_velocity_no_wait", "sum_trip_time", "sum_wait_time", "sum_speed_samples",
    "vehicle_steps", "env_steps",
)


def counters(sim: Simulator) -> dict[str, np.ndarray]:
    """A copy of the simulator's cumulative counters (for ``batch_summary(since=...)``)."""
    return {name: np.array(getattr(sim, name), copy=True) for name in COUNTERS}


def batch_summary(
    sim: Simulator, since: dict[str, np.ndarray] | None = None, use_kernel: bool | None = None
) -> dict[str, np.ndarray]:
    """Metrics of every environment of a simulator since its own last reset.

    Args:
        sim: The simulator.
        since: :func:`counters` taken earlier: the trip, speed, throughput, collision and time
            keys then cover only the steps since (a training chunk of a continuous run); the
            backlog, vehicle counts, released-style velocity and near-miss keys still cover
            the whole episode.
        use_kernel: compute with the compiled :mod:`mivecc_env.summary_kernel` (one call,
            bit-identical) or the numpy code below (the reference); default: the kernel when
            numba is available.

    Returns:
        ``SUMMARY_KEYS`` -> (B,) float64 arrays (environment ``b`` at index ``b``; with the
        kernel, the rows of one fresh (23, B) array).
    """
    if summary_kernel.HAVE_NUMBA if use_kernel is None else use_kernel:
        return dict(zip(SUMMARY_KEYS, _summary_table(sim, since), strict=True))
    now = {name: getattr(sim, name) for name in COUNTERS}
    if since is not None:
        now = {name: now[name] - since[name] for name in COUNTERS}
    exited = now["exited"].astype(np.float64)
    has = now["exited"] > 0
    n = np.maximum(exited, 1.0)
    sim_time = now["env_steps"] * sim.config.dt_s

    def per_exit(total: np.ndarray) -> np.ndarray:
        return np.where(has, total / n, 0.0)

    return {
        "avg_travel_velocity_mps": per_exit(now["sum_travel_velocity"]),
        "avg_travel_velocity_no_wait_mps": per_exit(now["sum_travel_velocity_no_wait"]),
        "upper_bound_mps": np.full(sim.batch_size, upper_bound_velocity_mps(sim.config)),
        "mean_speed_mps": now["sum_speed_samples"] / np.maximum(now["vehicle_steps"], 1),
        "throughput": exited,
        "throughput_vph": np.where(
            sim_time > 0, exited * 3600.0 / np.where(sim_time > 0, sim_time, 1.0), 0.0
        ),
        "collisions": now["collision_events"].astype(np.float64),
        "collided_vehicles": now["collided"].astype(np.float64),
        "released_check_collisions": now["released_flagged"].astype(np.float64),
        "backlog": sim.queued.astype(np.float64),
        "in_network": sim.in_network.astype(np.float64),
        "arrived": sim.arrived.astype(np.float64),
        "mean_trip_time_s": per_exit(now["sum_trip_time"]),
        "mean_wait_time_s": per_exit(now["sum_wait_time"]),
        "sim_time_s": sim_time.astype(np.float64),
        **released_and_near_miss(sim),
    }


def _summary_table(sim: Simulator, since: dict[str, np.ndarray] | None) -> np.ndarray:
    """(23, B) summary of every environment, rows in ``SUMMARY_KEYS`` order (compiled)."""
    now = {name: getattr(sim, name) for name in COUNTERS}
    if since is not None:
        now = {name: now[name] - since[name] for name in COUNTERS}
    nm, passing, arrivals = sim.near_miss, sim.passing, sim.arrivals
    return summary_kernel.fill(
        np.empty((summary_kernel.N_KEYS, sim.batch_size)), now, sim.config.dt_s,
        _upper_bound_of(sim.config), sim.active, arrivals.arrived, arrivals.entered,
        passing.count, passing.sum_time_s, passing.sum_length_m, nm.min_ttc_s, nm.ttc_hist,
        nm.min_pet_s, nm.pet_samples, nm.pet_under, nm.min_distance_m,
        near_miss.TTC_PERCENTILE, near_miss.TTC_BIN_S)


def episode_summary(sim: Simulator, env: int = 0) -> dict[str, float]:
    """Metrics of environment ``env`` of a simulator since its last reset (floats).

    ``float(batch_summary(sim)[key][env])`` for every key; with numba one compiled call (the
    ParallelEnv puts this summary in its infos every step, where the numpy reference's many
    small calls cost more than the rest of the infos together).

    Raises:
        IndexError: ``env`` not an integer in ``[-B, B)``.
    """
    env = check_env_index(env, sim.batch_size)
    if summary_kernel.HAVE_NUMBA:
        return dict(zip(SUMMARY_KEYS, _summary_table(sim, None)[:, env].tolist(), strict=True))
    return {key: float(value[env]) for key, value in batch_summary(sim).items()}


def released_and_near_miss(sim: Simulator) -> dict[str, np.ndarray]:
    """The released-style velocity and near-miss keys of every environment, (B,) float64."""
    return {
        "released_velocity_mps": np.asarray(sim.passing.velocity_mps(), dtype=np.float64),
        "released_passed": sim.passing.count.astype(np.float64),
        **sim.near_miss.batch_summary(),
    }
