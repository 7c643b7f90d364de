"""Accounting invariant: arrived == queued + in_network + exited + collided, at every step."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator


def check_invariant(sim: Simulator) -> None:
    arrived = sim.arrived
    rhs = sim.queued + sim.in_network + sim.exited + sim.collided
    np.testing.assert_array_equal(arrived, rhs)
    assert np.all(sim.arrivals.queued >= 0)
    assert np.all(sim.in_network == sim.active.sum(axis=1))
    assert sim.view.n_vehicles == int(sim.active.sum())


@settings(deadline=None, max_examples=20, derandomize=True)
@given(
    rows=st.integers(1, 2),
    cols=st.integers(1, 2),
    density=st.floats(300.0, 3000.0),
    end_rule=st.sampled_from(["sensible", "literal"]),
    same_lane_rule=st.booleans(),
    control=st.sampled_from(["unsignalized", "signalized"]),
    scheme=st.sampled_from(["E", "EE", "EEC"]),
    seed=st.integers(0, 2**31 - 1),
    batch=st.integers(1, 3),
    steps=st.integers(100, 400),
)
def test_invariant_every_step(
    rows: int, cols: int, density: float, end_rule: str, same_lane_rule: bool, control: str,
    scheme: str, seed: int, batch: int, steps: int,
) -> None:
    cfg = MiVeCCConfig(
        rows=rows, cols=cols, density_vplh=density, end_rule=end_rule,  # type: ignore[arg-type]
        same_lane_rule=same_lane_rule, control=control, scheme=scheme,  # type: ignore[arg-type]
    )
    sim = Simulator(cfg, batch_size=batch, seed=seed, capacity=8)  # small: forces growth
    rng = np.random.default_rng(seed)
    check_invariant(sim)
    for _ in range(steps):
        # random coordinator actions (NaN for some vehicles) stress collisions and exits
        shape = (batch, sim.capacity)
        edge = np.where(rng.random(shape) < 0.2, np.nan, rng.uniform(-3.0, 3.0, shape))
        cloud = rng.uniform(-3.0, 3.0, shape)
        events = sim.step(edge, cloud)
        check_invariant(sim)
        assert np.all(events.entered >= 0)
        assert np.all(events.collided_vehicles >= 2 * (events.collision_events > 0))
    assert sim.arrived.sum() > 0


def test_counters_match_events() -> None:
    sim = Simulator(MiVeCCConfig(rows=2, cols=2, density_vplh=2100), batch_size=2, seed=4)
    totals = np.zeros((4, 2), dtype=np.int64)
    for _ in range(600):
        ev = sim.step()
        totals += np.stack([ev.exited, ev.collided_vehicles, ev.collision_events, ev.entered])
        check_invariant(sim)
    np.testing.assert_array_equal(totals[0], sim.exited)
    np.testing.assert_array_equal(totals[1], sim.collided)
    np.testing.assert_array_equal(totals[2], sim.collision_events)
    np.testing.assert_array_equal(totals[3], sim.arrivals.entered.sum(axis=1))
    assert sim.exited.sum() > 0
