"""Reservation (AIM FCFS): never overlapping slots, trajectories followed, zero collisions."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import intersection_plan as ip
from mivecc_env.sim import safe_following as sf
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.reservation import ReservationBook, ReservationControl
from tests.sim._scenario import EAST, NORTH, place

DENSITIES = (300, 600, 900, 1200, 1500, 1800, 2100)


def _cfg(rows: int = 1, density: float = 900.0) -> MiVeCCConfig:
    return MiVeCCConfig(rows=rows, cols=rows, control="reservation", density_vplh=density)


def _assert_no_overlap(book: ReservationBook) -> int:
    """Every pair of grants of crossing lanes at one conflict point is ``buffer`` apart."""
    log = np.asarray(book.log, dtype=np.int64).reshape(-1, 5)
    checked = 0
    for key in np.unique(log[:, :2], axis=0):
        rows = log[(log[:, 0] == key[0]) & (log[:, 1] == key[1])]
        for i in range(len(rows)):
            for j in range(i + 1, len(rows)):
                if rows[i, 2] == rows[j, 2]:
                    continue
                checked += 1
                apart = (rows[i, 4] + book.buffer < rows[j, 3]) or (
                    rows[j, 4] + book.buffer < rows[i, 3])
                assert apart, (rows[i], rows[j])
    return checked


def _run(rows: int, density: float, steps: int, seed: int = 0) -> Simulator:
    sim = Simulator(_cfg(rows, density), seed=seed)
    sim.controller.book.record = True
    v_max, b = sim.config.v_max_mps, sim.config.a_max_mps2
    for _ in range(steps):
        sim.step()
        act = sim.active
        assert np.all(sim.v[act] >= 0.0) and np.all(sim.v[act] <= v_max + 1e-9)
        assert np.all(np.abs(sim.a[act]) <= b + 1e-6)
    np.testing.assert_array_equal(sim.arrived, sim.queued + sim.in_network + sim.exited
                                  + sim.collided)
    return sim


def test_book_detects_overlap_only_with_crossing_lanes() -> None:
    book = ReservationBook(1, 4, buffer_steps=2)
    book.grant(0, 1, lane=0, first=100, last=110)
    first = np.array([90, 95, 111, 113, 100])
    last = np.array([97, 98, 120, 130, 110])
    hit = book.conflicts(0, 1, lane=2, first=first, last=last, now=50)
    assert hit.tolist() == [False, True, True, False, True]
    # the same lane never conflicts (same-lane spacing is the safe-following rule's job)
    assert not book.conflicts(0, 1, lane=0, first=first, last=last, now=50).any()
    # expired slots are dropped
    assert not book.conflicts(0, 1, lane=2, first=first, last=last, now=200).any()


def test_safe_accel_keeps_the_invariant_against_a_braking_leader() -> None:
    rng = np.random.default_rng(0)
    b, dt, gap = 3.0, 0.1, 2.5
    for _ in range(200):
        v_l, v_f = rng.uniform(0, 13, 2)
        s_l = 100.0
        d_l = sf.stopping_point(s_l, v_l, b)
        # a follower state that satisfies the invariant
        s_f = s_l - gap - rng.uniform(0, 30)
        if sf.stopping_point(s_f, v_f, b) > d_l - gap:
            continue
        for _ in range(200):  # leader brakes as hard as allowed, follower as fast as allowed
            a = sf.safe_accel(np.array([s_f]), np.array([v_f]), np.array([s_l]),
                              np.array([v_l]), gap, b, dt)[0]
            assert a >= -b - 1e-6
            a = min(a, b)
            a = max(a, -v_f / dt)
            s_f, v_f = s_f + v_f * dt + 0.5 * a * dt * dt, v_f + a * dt
            s_l, v_l = sf.brake_step(np.array(s_l), np.array(v_l), b, dt)
            s_l, v_l = float(s_l), float(v_l)
            assert s_l - s_f >= gap - 0.005  # discrete stop overshoot b dt^2 / 8


def test_two_crossing_vehicles_get_disjoint_slots() -> None:
    sim = Simulator(_cfg(density=1.0), seed=0)
    ctl: ReservationControl = sim.controller
    ctl.book.record = True
    # east- and northbound vehicles equally far from their first conflict point
    place(sim, [(EAST, 70.0, 10.0), (NORTH, 70.0, 10.0)])
    for _ in range(120):
        sim.step()
    assert ctl.requests >= 2
    assert _assert_no_overlap(ctl.book) >= 1
    assert sim.collision_events.tolist() == [0]
    assert ctl.deviations == 0


def test_refused_vehicle_stops_before_the_conflict_zone() -> None:
    cfg = _cfg(density=1.0)
    sim = Simulator(cfg, seed=0)
    ctl: ReservationControl = sim.controller
    # Block both conflict points of the eastbound lane for a long time (a crossing lane's slot).
    for cp in range(sim.network.n_cp):
        ctl.book.grant(0, cp, lane=NORTH, first=0, last=10_000)
    place(sim, [(EAST, 80.0, 13.0)])
    stop = 150.0 - cfg.lane_offset_m - ip.occupancy_radius_m(cfg)
    for _ in range(300):
        sim.step()
        assert sim.s[0, 0] <= stop + 0.005  # discrete stop overshoot b dt^2 / 8
    assert ctl.refusals >= 5
    assert sim.v[0, 0] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("density", [300, 1200, 2100])
def test_short_runs_collision_free(density: int) -> None:
    sim = _run(1, density, 600)
    ctl = sim.controller
    assert sim.collision_events.tolist() == [0]
    assert ctl.deviations == 0 and ctl.infeasible == 0
    assert sim.exited[0] > 0
    _assert_no_overlap(ctl.book)


@pytest.mark.slow
@pytest.mark.parametrize("rows", [1, 3])
@pytest.mark.parametrize("density", DENSITIES)
def test_long_runs_collision_free_at_every_density(rows: int, density: int) -> None:
    sim = _run(rows, density, 3000 if rows == 1 else 2000, seed=density)
    ctl = sim.controller
    assert sim.collision_events.tolist() == [0]
    assert sim.collided.tolist() == [0]
    assert ctl.deviations == 0 and ctl.infeasible == 0
    assert _assert_no_overlap(ctl.book) > 0
    assert sim.exited[0] > 50


def test_batched_environments_match_single_runs() -> None:
    cfg = _cfg(density=1500)
    batch = Simulator(cfg, batch_size=2, seed=[3, 4])
    single = Simulator(cfg, seed=[4])
    for _ in range(400):
        batch.step()
        single.step()
    m = batch.active[1]
    np.testing.assert_allclose(np.sort(batch.s[1, m]), np.sort(single.s[0, single.active[0]]))
    assert batch.exited[1] == single.exited[0]
