"""DOOC-style optimisation: feasible schedules, brute-force optimum on tiny instances, a run."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("scipy")

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import optimisation as op
from mivecc_env.sim.core import Simulator


def _instance(rng: np.random.Generator, n: int) -> tuple:
    lane = rng.integers(0, 4, n)
    earliest = rng.uniform(0.0, 4.0, n)
    # vehicles of one lane in lane order: earliest times increasing along the lane
    for ln in range(4):
        idx = np.flatnonzero(lane == ln)
        earliest[idx] = np.sort(earliest[idx])
    latest = earliest + rng.uniform(3.0, 15.0, n)
    return earliest, latest, lane, lane < 2


def test_constructed_instance_schedule() -> None:
    # two crossing vehicles arriving together and a follower of the first one
    earliest = np.array([1.0, 1.0, 1.2])
    latest = np.full(3, 20.0)
    lane = np.array([0, 2, 0])
    t = op.schedule_milp(earliest, latest, lane, lane < 2, 1.5)
    assert op.check_schedule(t, earliest, latest, lane, lane < 2, 1.5) == []
    # optimum: lane 0 first (1.0, 2.5) and the crossing vehicle at 4.0 costs 4.3; crossing
    # vehicle first (1.0, then 2.5, 4.0) costs 1.5 + 2.8 = 4.3 too: total delay 4.3
    assert np.sum(t - earliest) == pytest.approx(4.3)


@pytest.mark.parametrize("seed", range(12))
def test_milp_matches_brute_force_on_tiny_instances(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 6))
    earliest, latest, lane, horizontal = _instance(rng, n)
    best, _ = op.schedule_brute_force(earliest, latest, lane, horizontal, 1.5)
    t = op.schedule_milp(earliest, latest, lane, horizontal, 1.5)
    if np.isfinite(best):
        assert op.check_schedule(t, earliest, latest, lane, horizontal, 1.5) == []
        assert np.sum(t - earliest) == pytest.approx(best, abs=1e-5)


def test_fixed_vehicles_keep_their_times() -> None:
    earliest = np.array([0.0, 0.5, 0.2])
    lane = np.array([0, 2, 3])
    fixed = np.array([0.3, np.nan, np.nan])
    t = op.schedule_milp(earliest, np.full(3, 30.0), lane, lane < 2, 1.5, fixed)
    assert t[0] == pytest.approx(0.3)
    assert op.check_schedule(t, np.array([0.3, 0.5, 0.2]), np.full(3, 30.0), lane, lane < 2,
                             1.5) == []


def test_arrival_times_are_kinematically_consistent() -> None:
    # from 10 m/s: accelerate to 13 in 1 s over 11.5 m, then 13 m/s
    assert op.arrival_time_s(11.5, 10.0, 13.0, 3.0) == pytest.approx(1.0)
    assert op.arrival_time_s(24.5, 10.0, 13.0, 3.0) == pytest.approx(2.0)
    # slow to 7 (1 s, 8.5 m), hold, sprint back to 13 (2 s, 20 m): 8.5 + 7 + 20 m in 4 s
    assert op.slow_then_sprint_time_s(35.5, 10.0, 7.0, 13.0, 3.0) == pytest.approx(4.0)
    assert np.isnan(op.slow_then_sprint_time_s(10.0, 10.0, 3.0, 13.0, 3.0))


def test_optimisation_mode_runs_and_counts_collisions() -> None:
    cfg = MiVeCCConfig(rows=1, cols=1, control="optimisation", density_vplh=600)
    sim = Simulator(cfg, seed=2)
    for _ in range(600):
        sim.step()
    assert sim.controller.solves > 10
    assert sim.exited[0] > 10
    np.testing.assert_array_equal(sim.arrived, sim.queued + sim.in_network + sim.exited
                                  + sim.collided)
    assert np.all(sim.v[sim.active] >= 0.0)


@pytest.mark.parametrize("seed", range(6))
def test_milp_is_feasible_and_no_worse_than_first_come_first_served(seed: int) -> None:
    # instances too large for the brute force (6-9 vehicles): the MILP's schedule keeps every
    # headway and bound, and its total delay is at most that of serving by earliest arrival
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(6, 10))
    earliest, _, lane, horizontal = _instance(rng, n)
    latest = np.full(n, 1e3)
    t = op.schedule_milp(earliest, latest, lane, horizontal, 1.5)
    assert op.check_schedule(t, earliest, latest, lane, horizontal, 1.5) == []
    fcfs = op.greedy_times(np.argsort(earliest, kind="stable"), earliest, lane, horizontal, 1.5)
    assert op.check_schedule(fcfs, earliest, latest, lane, horizontal, 1.5) == []
    assert np.sum(t - earliest) <= np.sum(fcfs - earliest) + 1e-6


def test_committed_vehicles_too_close_fall_back_to_a_greedy_schedule() -> None:
    # two committed crossing vehicles only 0.5 s apart make the MILP infeasible; the free
    # vehicle is still scheduled a headway after both of them, the committed ones unchanged
    earliest = np.array([1.0, 1.5, 0.5])
    lane = np.array([0, 2, 1])
    fixed = np.array([1.0, 1.5, np.nan])
    t = op.schedule_milp(earliest, np.full(3, 30.0), lane, lane < 2, 1.5, fixed)
    assert t[:2].tolist() == [1.0, 1.5]
    # lane 1 runs parallel to lane 0 (no constraint) and crosses lane 2
    assert t[2] == pytest.approx(1.5 + 1.5)
