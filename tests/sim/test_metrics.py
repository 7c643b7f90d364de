"""Metrics: the theoretical upper bound by hand, and episode summaries."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.metrics import (
    INF_WHEN_NO_DATA,
    SUMMARY_KEYS,
    batch_summary,
    counters,
    episode_summary,
    min_travel_time_s,
    upper_bound_velocity_mps,
)
from mivecc_env.sim.core import Simulator
from tests.sim._scenario import EAST, NORTH, place

# Enter at 10 m/s, accelerate at 3 m/s^2 to 13 m/s: 1 s and (13^2 - 10^2) / 6 = 11.5 m,
# then cruise at 13 m/s.
#   600 m: t = 1 + (600 - 11.5) / 13 = 46.2692 s -> 600 / t = 12.96758 m/s
#   450 m: t = 1 + 438.5 / 13 = 34.7308 s      -> 12.95681 m/s
#   300 m: t = 1 + 288.5 / 13 = 23.1923 s      -> 12.93532 m/s
V600, V450, V300 = 12.967581047381547, 12.956810631229235, 12.935323383084576


def test_min_travel_time() -> None:
    np.testing.assert_allclose(
        min_travel_time_s(MiVeCCConfig(), np.array([600.0, 300.0, 11.5])),
        [46.26923076923077, 23.192307692307693, 1.0],
    )
    # shorter than the acceleration distance: 5 = 10 t + 1.5 t^2 -> t = (-10 + sqrt 130) / 3
    assert float(min_travel_time_s(MiVeCCConfig(), 5.0)) == pytest.approx(0.4672514169971264)


def test_upper_bound_3x3() -> None:
    assert upper_bound_velocity_mps(MiVeCCConfig()) == pytest.approx(V600, abs=1e-9)


def test_upper_bound_1x1() -> None:
    assert upper_bound_velocity_mps(MiVeCCConfig(rows=1, cols=1)) == pytest.approx(V300, abs=1e-9)


def test_upper_bound_rectangular() -> None:
    # 1x2: two 450 m horizontal lanes, four 300 m vertical lanes: (2 V450 + 4 V300) / 6
    cfg = MiVeCCConfig(rows=1, cols=2)
    assert upper_bound_velocity_mps(cfg) == pytest.approx(12.942485799132797, abs=1e-9)


def test_summary_of_a_fresh_simulator() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1), seed=0)
    summary = episode_summary(sim)
    assert tuple(summary) == SUMMARY_KEYS
    assert all(isinstance(v, float) for v in summary.values())
    assert summary["upper_bound_mps"] == pytest.approx(V300, abs=1e-9)
    for key in SUMMARY_KEYS:
        if key in INF_WHEN_NO_DATA:
            assert summary[key] == np.inf, key  # no sample yet
        elif key != "upper_bound_mps":
            assert summary[key] == 0.0, key


def test_summary_of_an_environment_the_simulator_lacks_names_it() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=2, seed=0)
    assert episode_summary(sim, -1) == episode_summary(sim, 1)
    for env in (2, -3, 1.0, True):
        with pytest.raises(IndexError, match=rf"^env: must be an integer in \[-2, 2\) \(the "
                           rf"simulator holds 2 environments\), got {env}$"):
            episode_summary(sim, env)  # type: ignore[arg-type]


def test_a_lone_vehicle_reaches_the_upper_bound() -> None:
    # alone on the road (SV = +20 -> a = +3), it accelerates to 13 m/s in 1 s, then cruises:
    # exit at 23.1923 s, travel velocity 300 / 23.1923 = the 1x1 upper bound
    sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=1.0), seed=1)
    place(sim, [(EAST, 0.0, 10.0)])
    for _ in range(240):
        sim.step()
    assert sim.arrived.tolist() == [0], "precondition: no random arrival in 24 s"
    s = episode_summary(sim)
    assert s["throughput"] == 1.0
    assert s["avg_travel_velocity_mps"] == pytest.approx(V300, abs=1e-6)
    assert s["avg_travel_velocity_no_wait_mps"] == pytest.approx(V300, abs=1e-6)
    assert s["mean_trip_time_s"] == pytest.approx(23.192307692307693, abs=1e-6)
    assert s["mean_wait_time_s"] == 0.0
    assert s["sim_time_s"] == pytest.approx(24.0)
    assert s["throughput_vph"] == pytest.approx(3600.0 / 24.0)
    assert s["collisions"] == s["collided_vehicles"] == s["in_network"] == 0.0
    # released-style velocity: the mark is 150 + 5 = 155 m; reached at 1 + 143.5 / 13 s
    assert s["released_passed"] == 1.0
    assert s["released_velocity_mps"] == pytest.approx(155.0 / (1.0 + 143.5 / 13.0), abs=1e-9)
    # alone: no TTC or PET sample, no pair of vehicles
    for key in ("min_ttc_s", "ttc_p1_s", "min_pet_s", "min_distance_m"):
        assert s[key] == np.inf, key
    assert s["pet_samples"] == s["pet_under_1s"] == 0.0
    # mean speed over its 232 vehicle-steps: 10 steps at 10.3, 10.6, ..., 13.0, then 13.0
    steps = int(sim.vehicle_steps[0])
    assert steps == 232
    assert s["mean_speed_mps"] == pytest.approx((116.5 + 13.0 * (steps - 10)) / steps)


def test_waiting_counts_in_the_trip() -> None:
    # a vehicle that arrived 5 s before entering: its trip is 5 s longer
    sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=1.0), seed=1)
    place(sim, [(EAST, 0.0, 10.0)])
    sim.t_arrive[0, 0] = -5.0
    for _ in range(240):
        sim.step()
    s = episode_summary(sim)
    assert s["mean_wait_time_s"] == pytest.approx(5.0)
    assert s["mean_trip_time_s"] == pytest.approx(28.192307692307693, abs=1e-6)
    assert s["avg_travel_velocity_mps"] == pytest.approx(300.0 / 28.192307692307693, abs=1e-6)
    assert s["avg_travel_velocity_no_wait_mps"] == pytest.approx(V300, abs=1e-6)


def test_summary_consistent_with_counters() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=1200), batch_size=2, seed=3)
    for _ in range(600):
        sim.step()
    for env in range(2):
        s = episode_summary(sim, env)
        assert s["arrived"] == s["backlog"] + s["in_network"] + s["throughput"] + s[
            "collided_vehicles"]
        assert s["throughput"] > 0
        assert 6.0 <= s["mean_speed_mps"] <= 13.0
        assert s["avg_travel_velocity_mps"] <= s["upper_bound_mps"] + 1e-9
        assert s["avg_travel_velocity_no_wait_mps"] >= s["avg_travel_velocity_mps"]


def test_a_collision_shows_in_the_minimum_distance() -> None:
    # east 1 m and north 1 m before their shared conflict point, both at 10 m/s: after one
    # step both stand on it (distance 0): one collision event, minimum distance below 2 m
    sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=1.0), seed=1)
    place(sim, [(EAST, 154.0, 10.0), (NORTH, 144.0, 10.0)])
    sim.step()
    s = episode_summary(sim)
    assert s["collisions"] == 1.0
    assert s["min_distance_m"] < 2.0


def test_partial_reset_clears_the_new_measures_of_that_environment_only() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=2100), batch_size=2, seed=0)
    for _ in range(300):
        sim.step()
    before = episode_summary(sim, 1)
    assert before["released_passed"] > 0 and before["pet_samples"] > 0
    sim.reset_at([0], seeds=[5])
    fresh = episode_summary(sim, 0)
    assert fresh["released_passed"] == fresh["pet_samples"] == 0.0
    assert fresh["released_velocity_mps"] == 0.0
    assert fresh["min_ttc_s"] == fresh["min_pet_s"] == fresh["min_distance_m"] == np.inf
    assert episode_summary(sim, 1) == before


@pytest.mark.parametrize(
    ("overrides", "batch"),
    [({"rows": 3, "cols": 3, "density_vplh": 2100}, 1),
     ({"rows": 1, "cols": 1, "density_vplh": 2400, "model": "released"}, 3),
     ({"rows": 1, "cols": 2, "density_vplh": 600, "control": "signalized"}, 2)],
)
def test_compiled_summary_is_the_numpy_reference_bit_for_bit(overrides: dict, batch: int) -> None:
    """``batch_summary`` (compiled with numba) and ``episode_summary`` (the ParallelEnv's infos
    every step) equal the numpy reference exactly, from the empty network on, across a partial
    reset, and per chunk (``since``)."""
    sim = Simulator(MiVeCCConfig(**overrides), batch_size=batch, seed=1)
    since = counters(sim)

    def hexed(summary: dict) -> dict:
        return {k: np.asarray(v, dtype=np.float64).tobytes().hex() for k, v in summary.items()}

    for step in range(601):
        if step == 300 and batch > 1:
            sim.reset_at([1], seeds=[9])
        if step == 120:
            since = counters(sim)
        if step % 23 == 0 or step == 600:
            ref = batch_summary(sim, use_kernel=False)
            assert hexed(batch_summary(sim)) == hexed(ref)
            assert hexed(batch_summary(sim, since)) == hexed(
                batch_summary(sim, since, use_kernel=False))
            for env in range(batch):
                got = episode_summary(sim, env)
                assert tuple(got) == SUMMARY_KEYS
                assert all(type(v) is float for v in got.values())
                assert hexed(got) == hexed({k: v[env] for k, v in ref.items()})
        sim.step()
    final = batch_summary(sim, use_kernel=False)
    # the compared values include real trips and TTC samples, not only their empty defaults
    assert final["throughput"][0] > 0 and np.isfinite(final["ttc_p1_s"][0])
