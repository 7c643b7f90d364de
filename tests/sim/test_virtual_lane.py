"""Virtual lanes: projection of crossing vehicles, neighbours, window, density indicator."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.virtual_lane import VirtualLaneView, density_indicator
from tests.sim._scenario import EAST, NORTH, SOUTH, WEST, hand_sim, place

INF = np.inf

# 1x1 grid (300 m lanes). Conflict points, as (s on the horizontal, s on the vertical lane):
#   E x S (145, 155)   E x N (155, 145)   W x N (145, 155)   W x S (155, 145)


def _points_of_lane(view: VirtualLaneView, lane: int) -> list[tuple[float, int, bool]]:
    """(position, vehicle, own) of the points on one virtual lane of env 0, in order."""
    sel = view.point_group == lane
    return [(float(p), int(v), bool(o)) for p, v, o in
            zip(view.point_pos[sel], view.point_vehicle[sel], view.point_own[sel], strict=True)]


@pytest.fixture
def scene() -> Simulator:
    sim = hand_sim()
    place(sim, [
        (EAST, 130.0, 10.0),  # 0: ego
        (SOUTH, 135.0, 10.0),  # 1: 20 m before E x S (155) -> on E at 145 - 20 = 125
        (NORTH, 100.0, 10.0),  # 2: 45 m before E x N (145) -> on E at 155 - 45 = 110
        (EAST, 170.0, 10.0),  # 3: own-lane leader of 0
        (NORTH, 60.0, 10.0),  # 4: 85 m before E x N: outside the 75 m window
    ])
    return sim


def test_projection_positions(scene: Simulator) -> None:
    view = scene.view
    assert _points_of_lane(view, EAST) == [
        (110.0, 2, False), (125.0, 1, False), (130.0, 0, True), (170.0, 3, True)
    ]
    # the southbound lane: its own vehicle 1 and eastbound 0 at 155 + (130 - 145) = 140;
    # eastbound 3 is 25 m past E x S, beyond the 10 m clearance: not projected; northbound
    # vehicles never project on it (parallel lanes)
    assert _points_of_lane(view, SOUTH) == [(135.0, 1, True), (140.0, 0, False)]
    # the northbound lane: E 0 at 145 + (130 - 155) = 120; E 3 is 15 m past E x N
    assert _points_of_lane(view, NORTH) == [(60.0, 4, True), (100.0, 2, True), (120.0, 0, False)]
    # the westbound lane: S 1 at 155 + (135 - 145) = 145, N 2 at 145 + (100 - 155) = 90
    assert _points_of_lane(view, WEST) == [(90.0, 2, False), (145.0, 1, False)]


def test_neighbours_and_gaps(scene: Simulator) -> None:
    view = scene.view
    np.testing.assert_array_equal(view.vehicle, [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(view.d_front, [40.0, 5.0, 20.0, INF, 40.0])
    np.testing.assert_array_equal(view.d_back, [5.0, INF, 40.0, 40.0, INF])
    np.testing.assert_array_equal(view.leader, [3, -1, -1, -1, 2])
    np.testing.assert_array_equal(view.follower, [-1, -1, 4, 0, -1])
    # the nearest points of the ego: own-lane vehicle 3 ahead, projected vehicle 1 behind
    assert view.point_vehicle[view.front_point[0]] == 3
    assert view.point_own[view.front_point[0]]
    assert view.point_vehicle[view.back_point[0]] == 1
    assert not view.point_own[view.back_point[0]]
    assert view.front_point[3] == -1
    assert view.back_point[1] == -1


def test_crossing_gaps_are_symmetric(scene: Simulator) -> None:
    # ego (E, 15 m before E x S) and vehicle 1 (S, 20 m before it) are 5 m apart on both
    # virtual lanes
    view = scene.view
    assert view.d_back[0] == view.d_front[1] == 5.0


def test_projection_3x3() -> None:
    # southbound column 1 (lane 10) crosses eastbound row 0 (lane 0) at (295, 145):
    # s = 295 on the eastbound lane, 600 - 145 = 455 on the southbound lane
    sim = Simulator(MiVeCCConfig(), seed=0)
    place(sim, [(10, 435.0, 10.0), (0, 300.0, 10.0)])
    east = _points_of_lane(sim.view, 0)
    assert east == [(275.0, 0, False), (300.0, 1, True)]  # 20 m before 295
    assert sim.view.d_back[1] == 25.0
    # on the southbound lane the eastbound vehicle is 5 m past the point: 455 + 5 = 460
    assert _points_of_lane(sim.view, 10) == [(435.0, 0, True), (460.0, 1, False)]


@pytest.mark.parametrize(("s_north", "projected"), [(70.0, True), (69.99, False),
                                                    (155.0, True), (155.01, False)])
def test_window_boundary(s_north: float, projected: bool) -> None:
    # E x N at s_N = 145; a crossing vehicle is projected from 75 m before the point until
    # 10 m past it (projection_window_m, projection_clear_m), both ends closed
    sim = hand_sim()
    place(sim, [(NORTH, s_north, 10.0)])
    east = _points_of_lane(sim.view, EAST)
    assert (len(east) == 1) == projected
    if projected:
        assert east[0][0] == pytest.approx(155.0 + s_north - 145.0)


def test_window_is_a_config_field() -> None:
    sim = hand_sim(MiVeCCConfig(rows=1, cols=1, projection_window_m=10.0, projection_clear_m=3.0))
    # 11 and 9 m before E x N, 2 and 4 m past it
    place(sim, [(NORTH, 134.0, 10.0), (NORTH, 136.0, 10.0), (NORTH, 147.0, 10.0),
                (NORTH, 149.0, 10.0)])
    assert _points_of_lane(sim.view, EAST) == [(146.0, 1, False), (157.0, 2, False)]


def test_empty_and_lonely() -> None:
    sim = hand_sim()
    assert sim.view.n_vehicles == 0
    assert density_indicator(sim.view, 5).shape == (0,)
    place(sim, [(EAST, 10.0, 10.0)])
    view = sim.view
    assert (view.d_front[0], view.d_back[0]) == (INF, INF)
    assert (view.leader[0], view.follower[0]) == (-1, -1)
    np.testing.assert_array_equal(density_indicator(view, 5), [0.0])


def test_batch_envs_are_separate() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=2, seed=0)
    place(sim, [(EAST, 100.0, 10.0)], env=0)
    place(sim, [(EAST, 110.0, 10.0)], env=1)
    view = sim.view
    np.testing.assert_array_equal(view.env, [0, 1])
    np.testing.assert_array_equal(view.d_front, [INF, INF])
    np.testing.assert_array_equal(view.leader, [-1, -1])


def test_density_indicator_even_spacing() -> None:
    sim = hand_sim()
    place(sim, [(EAST, 20.0 * (k + 1), 10.0) for k in range(12)])  # 20, 40, ..., 240
    np.testing.assert_allclose(density_indicator(sim.view, 5), 0.0, atol=1e-12)


def test_density_indicator_one_perturbed_vehicle() -> None:
    # 13 vehicles at 10, 20, ..., 130, the 7th moved from 70 to 76. Lane mean spacing
    # (130 - 10) / 12 = 10. With n = 5 only windows ending at the moved vehicle change:
    #   k = 1:  points 0..6, (76 - 10) / 6 = 11  -> DI = 1
    #   k = 11: points 6..12, (130 - 76) / 6 = 9 -> DI = 1
    # and k = 6 itself spans 20..120: 100 / 10 = 10 -> DI = 0.
    sim = hand_sim()
    s = [10.0 * (k + 1) for k in range(13)]
    s[6] = 76.0
    place(sim, [(EAST, x, 10.0) for x in s])
    expected = np.zeros(13)
    expected[[1, 11]] = 1.0
    np.testing.assert_allclose(density_indicator(sim.view, 5), expected, atol=1e-12)
    # n = 1: vehicle 5 spans 50..76: 26 / 2 = 13 -> 3; 6 spans 60..80 -> 0;
    # 7 spans 76..90: 14 / 2 = 7 -> 3
    di1 = density_indicator(sim.view, 1)
    np.testing.assert_allclose(di1[5:8], [3.0, 0.0, 3.0], atol=1e-12)
    # end of the lane: vehicle 0 spans 10..20 (one spacing) -> 0
    assert di1[0] == pytest.approx(0.0, abs=1e-12)


def test_density_indicator_counts_projected_points() -> None:
    # E vehicles at 100, 140, 150 and a southbound vehicle at 130, projected onto the
    # eastbound lane at 145 + (130 - 155) = 120. The eastbound vehicles appear on the
    # southbound lane at 155 + (s - 145): 110, 150, 160.
    sim = hand_sim()
    place(sim, [(EAST, 100.0, 10.0), (EAST, 140.0, 10.0), (SOUTH, 130.0, 10.0),
                (EAST, 150.0, 10.0)])
    # E lane: 100, 120 (S), 140, 150 -> mean spacing 50 / 3; vehicle 0 (n = 1) spans
    # 100..120: 20 - 16.667 = 3.333; S lane: 110, 130, 150 (E 140), 160 (E 150) ...
    di = density_indicator(sim.view, 1)
    assert di[0] == pytest.approx(20.0 - 50.0 / 3.0, abs=1e-9)
    # vehicle 2 on the S lane: points 110, 130, 150, 160 -> mean 50 / 3; window 110..150
    # spans 2 spacings: 20 -> DI 3.333
    assert di[2] == pytest.approx(20.0 - 50.0 / 3.0, abs=1e-9)


def _brute_force_neighbours(sim: Simulator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """d_front, d_back and own-lane leader of every view vehicle, by a direct O(n^2) loop."""
    net, cfg, view = sim.network, sim.config, sim.view
    n = view.n_vehicles
    d_front, d_back = np.full(n, INF), np.full(n, INF)
    leader = np.full(n, -1)
    for i in range(n):
        lead_gap = INF
        for j in range(n):
            if i == j or view.env[i] != view.env[j]:
                continue
            if view.lane[j] == view.lane[i]:
                pos = view.s[j]
                if view.s[i] < pos < view.s[i] + lead_gap:
                    lead_gap, leader[i] = pos - view.s[i], j
            else:
                shared = np.flatnonzero(
                    ((net.cp_lane[:, 0] == view.lane[i]) & (net.cp_lane[:, 1] == view.lane[j]))
                    | ((net.cp_lane[:, 1] == view.lane[i]) & (net.cp_lane[:, 0] == view.lane[j]))
                )
                if shared.size == 0:
                    continue
                k = int(shared[0])
                side_i = 0 if net.cp_lane[k, 0] == view.lane[i] else 1
                delta = view.s[j] - net.cp_s[k, 1 - side_i]
                if not -cfg.projection_window_m <= delta <= cfg.projection_clear_m:
                    continue
                pos = net.cp_s[k, side_i] + delta
            gap = pos - view.s[i]
            if gap > 0:
                d_front[i] = min(d_front[i], gap)
            elif gap < 0:
                d_back[i] = min(d_back[i], -gap)
    return d_front, d_back, leader


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_view_matches_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    sim = Simulator(MiVeCCConfig(rows=2, cols=2), batch_size=2, seed=0)
    for env in range(2):
        count = 40
        lanes = rng.integers(0, sim.network.n_lanes, count)
        s = rng.uniform(0.0, 450.0, count)
        place(sim, list(zip(lanes.tolist(), s.tolist(), [10.0] * count, strict=True)), env=env)
    d_front, d_back, leader = _brute_force_neighbours(sim)
    view = sim.view
    np.testing.assert_allclose(view.d_front, d_front, atol=1e-9)
    np.testing.assert_allclose(view.d_back, d_back, atol=1e-9)
    np.testing.assert_array_equal(view.leader, leader)
    for i in np.flatnonzero(leader >= 0):
        assert view.follower[leader[i]] == i
