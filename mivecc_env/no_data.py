"""Reporting "no data" as NaN: summaries for people and files, not for the environments.

:func:`mivecc_env.metrics.episode_summary` never holds NaN, because it travels in the
environments' infos, where PettingZoo's and Gymnasium's determinism checks compare values with
``==`` (NaN != NaN). Its 0 for, say, the travel velocity of a run in which no vehicle has exited
yet would read as a standstill in a report, so reports (``mivecc evaluate``, the benchmark CSV
files, the training log) pass the summary through :func:`mark_no_data` first: NaN there is
``null`` in the CLI's JSON, ``nan`` in CSV files and a gap in plots.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

from mivecc_env.config import MiVeCCConfig
from mivecc_env.metrics import min_travel_time_s

__all__ = ["EXIT_KEYS", "mark_no_data", "shortest_trip_s"]

#: Summary keys averaged over exited vehicles: no data before the first exit.
EXIT_KEYS: tuple[str, ...] = (
    "avg_travel_velocity_mps", "avg_travel_velocity_no_wait_mps", "mean_trip_time_s",
    "mean_wait_time_s",
)


@functools.lru_cache(maxsize=64)
def shortest_trip_s(config: MiVeCCConfig) -> float:
    """Duration of the shortest possible trip [s]: the shorter grid side, no waiting."""
    length = (min(config.rows, config.cols) + 1) * config.segment_length_m
    return float(min_travel_time_s(config, length))


def mark_no_data(summary: Mapping[str, Any], config: MiVeCCConfig) -> dict[str, Any]:
    """A copy of an episode summary with NaN where nothing has been measured yet.

    * :data:`EXIT_KEYS` while no vehicle has exited (``throughput == 0``);
    * ``released_velocity_mps`` while no vehicle has passed its mark (``released_passed``);
    * ``mean_speed_mps`` while no vehicle has entered the network;
    * ``throughput_vph`` while no vehicle has exited and the shortest possible trip has not
      had time to end (later, 0 veh/h is a measured standstill).
    """
    out = dict(summary)
    nan = math.nan
    exited = out.get("throughput", 0.0)
    if exited == 0:
        for key in EXIT_KEYS:
            if key in out:
                out[key] = nan
        if "throughput_vph" in out and out.get("sim_time_s", 0.0) < shortest_trip_s(config):
            out["throughput_vph"] = nan
    if out.get("released_passed", 1) == 0 and "released_velocity_mps" in out:
        out["released_velocity_mps"] = nan
    entered = out.get("arrived", 1) - out.get("backlog", 0)
    if entered == 0 and "mean_speed_mps" in out:
        out["mean_speed_mps"] = nan
    return out
