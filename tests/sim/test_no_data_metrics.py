"""Metrics without data are NaN ("no data"), not 0 (which would read as a standstill)."""

from __future__ import annotations

import math

from mivecc_env.config import MiVeCCConfig
from mivecc_env.metrics import episode_summary, min_travel_time_s, shortest_trip_s
from mivecc_env.sim.core import Simulator

NO_EXIT_KEYS = ("avg_travel_velocity_mps", "avg_travel_velocity_no_wait_mps",
                "mean_trip_time_s", "mean_wait_time_s")


def test_shortest_trip_is_the_shorter_grid_side() -> None:
    cfg = MiVeCCConfig(rows=1, cols=3)
    assert shortest_trip_s(cfg) == float(min_travel_time_s(cfg, 2 * 150.0))


def test_before_any_exit_the_trip_metrics_have_no_data() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=2100), seed=0)
    s = episode_summary(sim)  # time 0: nothing entered
    assert math.isnan(s["mean_speed_mps"]) and math.isnan(s["throughput_vph"])
    for _ in range(20):
        sim.step()
    s = episode_summary(sim)
    assert sim.exited[0] == 0 and sim.in_network[0] > 0
    for key in NO_EXIT_KEYS:
        assert math.isnan(s[key]), key
    assert math.isnan(s["throughput_vph"])  # 2 s < the shortest trip (~23 s): no flow data
    assert s["throughput"] == 0.0  # a count: none exited
    assert 6.0 <= s["mean_speed_mps"] <= 13.0  # vehicles have moved: real data


def test_a_real_standstill_reads_zero_throughput() -> None:
    """Past the shortest trip time, no exit is a measured throughput of 0 veh/h."""
    cfg = MiVeCCConfig(rows=1, cols=1, density_vplh=1.0)  # almost no demand
    sim = Simulator(cfg, seed=0)
    steps = int(shortest_trip_s(cfg) / cfg.dt_s) + 2
    for _ in range(steps):
        sim.step()
    s = episode_summary(sim)
    assert sim.exited[0] == 0
    assert s["throughput_vph"] == 0.0


def test_after_exits_every_metric_is_finite() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=2100), seed=0)
    while sim.exited[0] == 0:
        sim.step()
    s = episode_summary(sim)
    assert all(math.isfinite(v) for v in s.values())
