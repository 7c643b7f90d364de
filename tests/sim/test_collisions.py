"""Collisions: closer than 2 m (Euclidean), own lane or crossing lanes; counted and removed."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator, collision_pairs
from tests.sim._scenario import EAST, NORTH, SOUTH, WEST, hand_sim, place

# 1x1 grid: E x S at (145, 145): s_E = 145, s_S = 155.


def pairs_of(vehicles: list[tuple[int, float]], s_new: list[float] | None = None,
             exited: list[bool] | None = None, config: MiVeCCConfig | None = None) -> np.ndarray:
    sim = hand_sim(config)
    place(sim, [(lane, s, 10.0) for lane, s in vehicles])
    view = sim.view
    s_after = view.s.copy() if s_new is None else np.array(s_new)
    out = np.zeros(view.n_vehicles, dtype=bool) if exited is None else np.array(exited)
    return collision_pairs(sim.network, view, s_after, out, sim.config.vehicle_length_m)


@pytest.mark.parametrize(("gap", "hit"), [(1.5, True), (1.99, True), (2.0, False), (2.5, False)])
def test_same_lane_threshold(gap: float, hit: bool) -> None:
    pairs = pairs_of([(EAST, 50.0), (EAST, 50.0 + gap)])
    assert pairs.tolist() == ([[0, 1]] if hit else [])


@pytest.mark.parametrize(
    ("s_east", "s_south", "hit"),
    [
        (144.0, 154.0, True),  # 1 m before the point each: hypot(1, 1) = 1.41
        (143.5, 153.5, False),  # 1.5 m each: 2.12
        (146.0, 156.0, True),  # 1 m past it each
        (144.0, 156.0, True),  # one before, one past
        (145.0, 153.01, True),  # 0 and 1.99
        (145.0, 153.0, False),  # 0 and 2.0: not closer than 2 m
        (143.6, 153.6, True),  # 1.4 m each: 1.98
    ],
)
def test_crossing_threshold(s_east: float, s_south: float, hit: bool) -> None:
    pairs = pairs_of([(EAST, s_east), (SOUTH, s_south)])
    assert pairs.tolist() == ([[0, 1]] if hit else [])


def test_crossing_distance_is_euclidean() -> None:
    sim = hand_sim()
    xy = sim.network.xy(np.array([EAST, SOUTH]), np.array([144.0, 154.0]))
    np.testing.assert_allclose(xy, [[144.0, 145.0], [145.0, 146.0]])
    assert np.hypot(*(xy[0] - xy[1])) == pytest.approx(1.4142135623730951)


def test_different_conflict_points_do_not_collide() -> None:
    # E at E x S (145, 145), N at E x N (155, 145): 10 m apart
    assert pairs_of([(EAST, 145.0), (NORTH, 145.0)]).size == 0


@pytest.mark.parametrize(
    ("lane_a", "s_a", "lane_b", "s_b"),
    [
        (EAST, 145.0, WEST, 155.0),  # same x = 145, 10 m apart (two lane offsets)
        (EAST, 150.0, WEST, 150.0),  # side by side at the centre
        (NORTH, 150.0, SOUTH, 150.0),
    ],
)
def test_opposite_directions_never_collide(lane_a: int, s_a: float, lane_b: int,
                                           s_b: float) -> None:
    assert pairs_of([(lane_a, s_a), (lane_b, s_b)]).size == 0


def test_opposite_directions_pass_through_the_box() -> None:
    # head-on traffic on the two lanes of a road meets in the middle without a collision
    sim = hand_sim()
    place(sim, [(EAST, 100.0, 10.0), (WEST, 100.0, 10.0), (NORTH, 100.0, 10.0),
                (SOUTH, 90.0, 10.0)])
    for _ in range(15):
        sim.step()
    assert sim.collided[0] == 0


def test_overtaking_within_a_step_collides() -> None:
    # the follower passes its leader between two views: negative gap < 2 m
    pairs = pairs_of([(EAST, 50.0), (EAST, 53.0)], s_new=[56.0, 54.0])
    assert pairs.tolist() == [[0, 1]]


def test_exited_vehicles_are_ignored() -> None:
    pairs = pairs_of([(EAST, 299.0), (EAST, 299.5)], s_new=[299.9, 300.5], exited=[False, True])
    assert pairs.size == 0


def test_three_vehicles_at_one_point() -> None:
    # E 144.5 and E 146 (same lane, 1.5 m), S 154.5: crossing distances hypot(0.5, 0.5) and
    # hypot(1.0, 0.5) = 1.118 -> three pairs
    pairs = pairs_of([(EAST, 144.5), (EAST, 146.0), (SOUTH, 154.5)])
    assert pairs.tolist() == [[0, 1], [0, 2], [1, 2]]


def test_vehicle_length_is_a_config_field() -> None:
    cfg = MiVeCCConfig(rows=1, cols=1, vehicle_length_m=4.0)
    assert pairs_of([(EAST, 50.0), (EAST, 53.0)], config=cfg).tolist() == [[0, 1]]
    # 2.5 m each from the point: 3.54 < 4
    assert pairs_of([(EAST, 142.5), (SOUTH, 152.5)], config=cfg).tolist() == [[0, 1]]
    assert pairs_of([(EAST, 142.0), (SOUTH, 152.0)], config=cfg).size == 0  # 4.24


# --- through a simulator step -----------------------------------------------------------
def test_step_same_lane_collision_removes_and_counts() -> None:
    # 1.5 m apart at 10 m/s: the rear one brakes at -3, the front one (its nearest is behind)
    # speeds up at +3; after 0.1 s the gap is 1.5 + 0.015 + 0.015 = 1.53 m < 2 m
    sim = hand_sim()
    place(sim, [(EAST, 50.0, 10.0), (EAST, 51.5, 10.0), (NORTH, 20.0, 10.0)])
    events = sim.step()
    assert events.collision_events.tolist() == [1]
    assert events.collided_vehicles.tolist() == [2]
    assert events.collided_env.tolist() == [0, 0]
    assert events.collided_area.tolist() == [-1, -1]  # 51 m: outside the control area
    assert sim.collided.tolist() == [2]
    assert sim.collision_events.tolist() == [1]
    assert sim.in_network.tolist() == [1]  # the northbound vehicle stays
    assert sim.active[0].tolist()[:3] == [False, False, True]
    assert sim.view.n_vehicles == 1
    # counters accumulate and are never reset by later steps
    sim.step()
    assert sim.collided.tolist() == [2]


def test_step_crossing_collision() -> None:
    # both 1 m before E x S: they meet within the step
    sim = hand_sim()
    place(sim, [(EAST, 144.0, 10.0), (SOUTH, 154.0, 10.0)])
    events = sim.step()
    assert events.collision_events.tolist() == [1]
    assert events.collided_vehicles.tolist() == [2]
    assert events.collided_area.tolist() == [0, 0]
    assert sim.in_network.tolist() == [0]


def test_step_collision_only_in_its_environment() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=2, seed=0)
    place(sim, [(EAST, 50.0, 10.0), (EAST, 51.5, 10.0)], env=1)
    place(sim, [(EAST, 50.0, 10.0), (EAST, 60.0, 10.0)], env=0)
    events = sim.step()
    assert events.collision_events.tolist() == [0, 1]
    assert sim.collided.tolist() == [0, 2]
    assert sim.in_network.tolist() == [2, 0]


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_collided_set_matches_brute_force(seed: int) -> None:
    # Vehicles crowded around the intersection centres of a 2x2 grid (two environments):
    # the vehicles in some pair closer than 2 m (Euclidean, any lanes) are exactly those in
    # collision_pairs, and every reported pair really is closer than 2 m.
    rng = np.random.default_rng(seed)
    sim = Simulator(MiVeCCConfig(rows=2, cols=2), batch_size=2, seed=0)
    for env in range(2):
        count = 60
        lanes = rng.integers(0, sim.network.n_lanes, count)
        centre = rng.integers(1, 3, count) * 150.0
        s = centre + rng.uniform(-9.0, 9.0, count)
        place(sim, list(zip(lanes.tolist(), s.tolist(), [10.0] * count, strict=True)), env=env)
    view = sim.view
    xy = sim.network.xy(view.lane, view.s)
    dist = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    close = (dist < 2.0) & (view.env[:, None] == view.env[None, :])
    np.fill_diagonal(close, False)
    expected = set(np.flatnonzero(close.any(axis=1)).tolist())
    pairs = collision_pairs(sim.network, view, view.s.copy(), np.zeros(view.n_vehicles, bool),
                            2.0)
    assert set(pairs.ravel().tolist()) == expected
    assert len(expected) > 4
    for i, j in pairs:
        assert close[i, j]
