"""Determinism: the same seeds give the same arrays, batch environments are independent."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator

CFG = MiVeCCConfig(rows=2, cols=1, density_vplh=1500)
STATE = ("active", "lane", "s", "v", "a", "t_arrive", "t_enter", "vid")
COUNTERS = ("exited", "collided", "collision_events", "sum_travel_velocity", "sum_trip_time",
            "sum_wait_time", "sum_speed_samples", "vehicle_steps")


def run(sim: Simulator, steps: int) -> Simulator:
    for _ in range(steps):
        sim.step()
    return sim


def env_state(sim: Simulator, env: int) -> dict[str, np.ndarray]:
    """The vehicles of one environment in id order plus its counters."""
    table = sim.vehicle_table(env)
    order = np.argsort(table["vid"])
    out = {k: v[order] for k, v in table.items()}
    m = sim.active[env]
    out["t_arrive"] = sim.t_arrive[env, m][order]
    out["t_enter"] = sim.t_enter[env, m][order]
    for name in COUNTERS:
        out[name] = np.asarray(getattr(sim, name)[env])
    out["arrived"] = sim.arrivals.arrived[env].copy()
    return out


def assert_same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_same_seed_same_arrays() -> None:
    a = run(Simulator(CFG, batch_size=2, seed=42), 400)
    b = run(Simulator(CFG, batch_size=2, seed=42), 400)
    for name in STATE + COUNTERS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.in_network.sum() > 0


def test_reset_restarts_the_same_run() -> None:
    sim = run(Simulator(CFG, seed=5), 300)
    first = env_state(sim, 0)
    sim.reset(5)
    assert sim.time_s == 0.0
    assert sim.in_network.tolist() == [0]
    assert_same(env_state(run(sim, 300), 0), first)


def test_different_seeds_differ() -> None:
    a = run(Simulator(CFG, seed=1), 300)
    b = run(Simulator(CFG, seed=2), 300)
    assert not np.array_equal(a.arrivals.arrived, b.arrivals.arrived)
    c = run(Simulator(CFG, batch_size=2, seed=1), 300)
    assert not np.array_equal(c.arrivals.arrived[0], c.arrivals.arrived[1])


def test_batch_env_equals_single_run_with_its_seed() -> None:
    # one seed per environment: environment b uses SeedSequence(seeds[b]), exactly what a
    # B = 1 simulator seeded with seeds[b] uses
    seeds = [11, 22, 33]
    batch = run(Simulator(CFG, batch_size=3, seed=seeds), 500)
    for b, seed in enumerate(seeds):
        single = run(Simulator(CFG, batch_size=1, seed=seed), 500)
        assert_same(env_state(batch, b), env_state(single, 0))


def test_batch_env_equals_single_run_with_its_spawned_seed() -> None:
    # one int seed for the batch: environment b gets SeedSequence(seed).spawn(B)[b]
    batch = run(Simulator(CFG, batch_size=2, seed=7), 500)
    children = batch._seed_sequences(7)
    for b in range(2):
        single = Simulator(CFG, batch_size=1, seed=0)
        single.arrivals.reset([children[b]])  # empty network at t = 0: same as a reset
        assert_same(env_state(batch, b), env_state(run(single, 500), 0))


def test_single_run_reproduces_env0_of_a_batch() -> None:
    batch = run(Simulator(CFG, batch_size=2, seed=7), 300)
    single = run(Simulator(CFG, batch_size=1, seed=7), 300)
    assert_same(env_state(batch, 0), env_state(single, 0))


def test_seed_list_length_checked() -> None:
    with pytest.raises(ValueError, match="seed"):
        Simulator(CFG, batch_size=2, seed=[1, 2, 3])
    with pytest.raises(ValueError, match="batch_size"):
        Simulator(CFG, batch_size=0)
