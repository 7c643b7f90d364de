"""Reports say "no data" (NaN) where nothing was measured, not 0 (a standstill); the env's own
summary stays NaN-free (it travels in infos, compared with == by determinism checks)."""

from __future__ import annotations

import math

from mivecc_env.config import MiVeCCConfig
from mivecc_env.metrics import episode_summary, min_travel_time_s
from mivecc_env.no_data import EXIT_KEYS, mark_no_data, shortest_trip_s
from mivecc_env.sim.core import Simulator


def test_shortest_trip_is_the_shorter_grid_side() -> None:
    cfg = MiVeCCConfig(rows=1, cols=3)
    assert shortest_trip_s(cfg) == float(min_travel_time_s(cfg, 2 * 150.0))


def test_before_any_exit_the_trip_metrics_have_no_data() -> None:
    cfg = MiVeCCConfig(rows=1, cols=1, density_vplh=2100)
    sim = Simulator(cfg, seed=0)
    fresh = mark_no_data(episode_summary(sim), cfg)
    assert math.isnan(fresh["mean_speed_mps"]) and math.isnan(fresh["throughput_vph"])
    for _ in range(20):
        sim.step()
    raw = episode_summary(sim)
    assert not any(math.isnan(v) for v in raw.values())  # the env's summary: never NaN
    s = mark_no_data(raw, cfg)
    assert sim.exited[0] == 0 and sim.in_network[0] > 0
    for key in EXIT_KEYS:
        assert raw[key] == 0.0 and math.isnan(s[key]), key
    assert math.isnan(s["throughput_vph"])  # 2 s < the shortest trip (~23 s): no flow data
    assert math.isnan(s["released_velocity_mps"])
    assert s["throughput"] == 0.0  # a count: none exited
    assert 6.0 <= s["mean_speed_mps"] <= 13.0  # vehicles have moved: real data


def test_a_real_standstill_reads_zero_throughput() -> None:
    """Past the shortest trip time, no exit is a measured throughput of 0 veh/h."""
    cfg = MiVeCCConfig(rows=1, cols=1, density_vplh=1.0)  # almost no demand
    sim = Simulator(cfg, seed=0)
    for _ in range(int(shortest_trip_s(cfg) / cfg.dt_s) + 2):
        sim.step()
    s = mark_no_data(episode_summary(sim), cfg)
    assert sim.exited[0] == 0
    assert s["throughput_vph"] == 0.0


def test_after_exits_nothing_is_marked() -> None:
    cfg = MiVeCCConfig(rows=1, cols=1, density_vplh=2100)
    sim = Simulator(cfg, seed=0)
    while sim.exited[0] == 0 or sim.passing.count[0] == 0:
        sim.step()
    raw = episode_summary(sim)
    assert mark_no_data(raw, cfg) == raw
