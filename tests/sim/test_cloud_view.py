"""The released model's cloud view (``cloud_view``) and cloud reward population
(``cloud_reward_population``), on constructed states.

1x1 grid: lanes 300 m long, the centre at 150 m. Eastbound and northbound cross at (east 155,
north 145); eastbound and southbound at (east 145, south 155).
"""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env import mivecc_v0
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.sim import cloud_view
from mivecc_env.sim.state_graph import cloud_graphs, cloud_population
from mivecc_env.sim.virtual_lane import density_indicator
from tests.sim._scenario import EAST, NORTH, SOUTH, WEST, hand_sim, place

REL = MiVeCCConfig(rows=1, cols=1, density_vplh=1.0, model="released", scheme="EEC", k_cloud=8)
# 0 ego east at 100; 1 south at 20 (far upstream: projected at 155 + 20 - 145... on the east
# lane at 145 + (20 - 155) = 10); 2 north at 135 (at 155 + (135 - 145) = 145 on the east lane);
# 3 north at 142 (would land at 152, past the east lane's last centre); 4 east at 152 (past
# its last centre)
SCENE = [(EAST, 100.0, 10.0), (SOUTH, 20.0, 11.0), (NORTH, 135.0, 12.0), (NORTH, 142.0, 9.0),
         (EAST, 152.0, 13.0)]


def _lane_points(view, group: int) -> list[tuple[float, int]]:
    sel = view.point_group == group
    return sorted(zip(np.round(view.point_pos[sel], 6).tolist(),
                      view.point_vehicle[sel].tolist(), strict=True))


def test_released_cloud_view_differs_from_the_windowed_one() -> None:
    sim = hand_sim(REL)
    place(sim, SCENE)
    net = sim.network
    cv = cloud_view.released_cloud_view(net, sim.active, sim.lane, sim.s)
    assert cv.vehicle.tolist() == sim.view.vehicle.tolist()
    assert cv.lane.tolist() == sim.view.lane.tolist()
    # the east lane: its own vehicle before the centre, the southbound vehicle far upstream
    # (outside the 75 m window), the first northbound one; not the second (past the centre
    # once projected) nor the eastbound one past the centre
    assert _lane_points(cv, EAST) == [(10.0, 1), (100.0, 0), (145.0, 2)]
    assert _lane_points(sim.view, EAST) == [(100.0, 0), (145.0, 2), (152.0, 3), (152.0, 4)]
    # the north lane sees the eastbound vehicle 3 m before the point until 5 m past it
    assert _lane_points(cv, NORTH) == [(90.0, 0), (135.0, 2), (142.0, 3), (142.0, 4)]
    # the south lane's point lies past its last centre: crossing vehicles only until 5 m
    # before it (the eastbound vehicle at 152 is 7 m past it)
    assert _lane_points(cv, SOUTH) == [(20.0, 1), (110.0, 0)]


def test_cloud_graph_reads_the_released_view() -> None:
    sim = hand_sim(REL)
    place(sim, SCENE)
    view, net = sim.view, sim.network
    v, a = sim.v.ravel()[view.vehicle], sim.a.ravel()[view.vehicle]
    pop = cloud_population(net, view, REL.cloud_pick_population)
    cv = cloud_view.cloud_virtual_lanes(net, REL, view, sim.active, sim.lane, sim.s)
    g = cloud_graphs(net, cv, density_indicator(cv, REL.di_n), v, a, 1, REL, pop)
    w = cloud_graphs(net, view, density_indicator(view, REL.di_n), v, a, 1, REL, pop)
    col = int(np.flatnonzero(g.view_index[0, 0] == 0)[0])
    scale = float(net.lane_length.max())
    # rows 1, 2: nearest first, positions relative to the ego; velocity channel from v
    np.testing.assert_allclose(g.obs[0, 0, 1:3, col, 0], np.array([45.0, -90.0]) / scale,
                               rtol=1e-6)
    v_ch = 2 * (np.array([12.0, 11.0]) - REL.v_min_mps) / (REL.v_max_mps - REL.v_min_mps) - 1
    np.testing.assert_allclose(g.obs[0, 0, 1:3, col, 1], v_ch, rtol=1e-6)
    assert not g.obs[0, 0, 3:, col].any()
    wcol = int(np.flatnonzero(w.view_index[0, 0] == 0)[0])
    np.testing.assert_allclose(w.obs[0, 0, 1:4, wcol, 0], np.array([45.0, 52.0, 52.0]) / scale,
                               rtol=1e-6)
    # the same picks (same population, same slots) in both
    assert sorted(g.slot[0, 0][g.mask[0, 0] > 0]) == sorted(w.slot[0, 0][w.mask[0, 0] > 0])


def test_default_model_keeps_the_windowed_view() -> None:
    sim = hand_sim(MiVeCCConfig(rows=1, cols=1))
    place(sim, SCENE)
    c = sim.config
    assert c.cloud_view == "window" and c.cloud_reward_population == "picks"
    assert cloud_view.cloud_virtual_lanes(sim.network, c, sim.view, sim.active, sim.lane,
                                          sim.s) is sim.view
    pop = np.ones(sim.view.n_vehicles, dtype=bool)
    assert cloud_view.reward_population(sim.network, c, sim.view, pop, None) is pop


def _brute_force_lane(net, lane_of, s_of, ego: int) -> list[tuple[float, int]]:
    """The released cloud virtual lane of ``ego`` from the definition, vehicle by vehicle."""
    last = cloud_view.last_centre_s(net)
    out = [(round(float(s_of[i]), 6), i) for i in range(s_of.size)
           if lane_of[i] == ego and s_of[i] < last[ego]]
    for c in range(net.lane_cp.shape[1]):
        m = net.lane_cp_other_lane[ego, c]
        if m < 0:
            continue
        cp_l, cp_m = net.lane_cp_s[ego, c], net.lane_cp_other_s[ego, c]
        for i in range(s_of.size):
            delta = s_of[i] - cp_m
            if lane_of[i] == m and delta <= net.lane_offset_m and cp_l + delta < last[ego]:
                out.append((round(float(cp_l + delta), 6), i))
    return sorted(out)


@pytest.mark.parametrize("seed", [0, 1])
def test_released_cloud_view_matches_its_definition_on_3x3(seed: int) -> None:
    sim = hand_sim(MiVeCCConfig(model="released", density_vplh=1.0))
    rng = np.random.default_rng(seed)
    net = sim.network
    n = 80
    lane = rng.integers(0, net.n_lanes, n)
    s = rng.uniform(0.0, 599.0, n)
    place(sim, [(int(lane[i]), float(s[i]), 10.0) for i in range(n)])
    cv = cloud_view.released_cloud_view(net, sim.active, sim.lane, sim.s)
    two_l = 2 * net.n_lanes
    for lane_id in range(net.n_lanes):
        got = _lane_points(cv, lane_id)
        assert got == _brute_force_lane(net, lane, s, lane_id), lane_id
    # every vehicle at or past its last centre sits in a group of its own lane + L
    parked = cv.point_group[cv.own_point] >= net.n_lanes
    assert (parked == (s >= cloud_view.last_centre_s(net)[lane])).all()
    assert (cv.point_group < two_l).all()
    # projections reach before the entry of the lane (negative positions)
    assert cv.point_pos.min() < 0.0


def test_cloud_view_field_is_validated() -> None:
    with pytest.raises(ConfigError, match="cloud_view"):
        MiVeCCConfig(cloud_view="whole")
    with pytest.raises(ConfigError, match="cloud_reward_population"):
        MiVeCCConfig(cloud_reward_population="controlled")


# --- the cloud reward population ------------------------------------------------------------
def test_reward_population_includes_the_5_m_past_the_last_centre() -> None:
    sim = hand_sim(REL)
    # before the centre; 3 m past it; 4.9 m past before the move (counted once more after);
    # past 5 m before the move; on the exit link; the northbound vehicle before its centre
    place(sim, [(EAST, 100.0, 10.0), (EAST, 152.0, 10.0), (EAST, 154.9, 10.0),
                (WEST, 155.2, 10.0), (WEST, 250.0, 10.0), (NORTH, 60.0, 10.0)])
    sim.step()
    view = sim.view
    s_before = dict(zip(sim.prev_positions[0].tolist(), sim.prev_positions[1].tolist(),
                        strict=True))
    assert [round(s_before[int(x)], 1) for x in view.vehicle] == [
        100.0, 152.0, 154.9, 155.2, 250.0, 60.0]
    assert 152.5 < view.s[1] < 155.0 and view.s[2] > 155.0  # about 3 m / 6 m past the centre
    picks = cloud_population(sim.network, view, REL.cloud_pick_population)
    assert picks.tolist() == [True, False, False, False, False, True]
    pop = cloud_view.reward_population(sim.network, REL, view, picks, sim.prev_positions)
    assert pop.tolist() == [True, True, True, False, False, True]
    # before the first move nobody counts; a vehicle that just entered (s = 0) does not
    assert not cloud_view.reward_population(sim.network, REL, view, picks, None).any()


def test_cloud_reward_over_the_released_population() -> None:
    env = BatchedMiVeCCEnv(REL, batch_size=1, observe=("cloud",))
    env.reset(seed=0)
    place(env.sim, [(EAST, 100.0, 8.0), (EAST, 140.0, 9.0), (EAST, 151.8, 12.0),
                    (EAST, 170.0, 13.0), (NORTH, 30.0, 11.0)])
    env._observe_and_pack(None)
    out = env.step(None, np.zeros((1, REL.k_cloud)))
    sim = env.sim
    s, v = sim.s[0, :5], sim.v[0, :5]
    assert sim.active[0, :5].all() and 152.5 < s[2] < 155.0  # about 3 m past the centre
    counted = [0, 1, 2, 4]  # the vehicle 3 m past the centre counts, the one at 170 not
    expected = float(np.mean(v[counted] - 12.0))
    assert out.cloud_terms["reward_velocity"][0] == pytest.approx(expected)
    # ... while the pick population (before the last centre) leaves it out
    paper_pop = env.config.replace(cloud_reward_population="picks")
    env2 = BatchedMiVeCCEnv(paper_pop, batch_size=1, observe=("cloud",))
    env2.reset(seed=0)
    place(env2.sim, [(EAST, 100.0, 8.0), (EAST, 140.0, 9.0), (EAST, 151.8, 12.0),
                     (EAST, 170.0, 13.0), (NORTH, 30.0, 11.0)])
    env2._observe_and_pack(None)
    out2 = env2.step(None, np.zeros((1, REL.k_cloud)))
    v2 = env2.sim.v[0, :5]
    assert out2.cloud_terms["reward_velocity"][0] == pytest.approx(
        float(np.mean(v2[[0, 1, 4]] - 12.0)))


def test_released_eec_env_runs_with_the_cloud_view() -> None:
    env = mivecc_v0.parallel_env(rows=3, cols=3, density=2100.0, model="released",
                                 scheme="EEC", max_steps=40)
    obs, _ = env.reset(seed=0)
    for _ in range(40):
        actions = {a: np.zeros(env.action_space(a).shape, dtype=np.float32)
                   for a in env.agents}
        obs, rewards, _, _, _ = env.step(actions)
    assert np.isfinite(rewards["cloud_0"])
    assert env.observation_space("cloud_0").contains(obs["cloud_0"])
