"""The cloud's pick population (``cloud_pick_population``) and its reward over the same vehicles.

1x1 grid, eastbound lane: conflict points at 145 and 155 m, the centre at 150 m, exit link
from 155 m on (lane end 300 m).
"""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env import mivecc_v0
from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.sim.state_graph import cloud_graphs, cloud_population
from mivecc_env.sim.virtual_lane import density_indicator
from tests.sim._scenario import EAST, NORTH, hand_sim, place

# before every point, between the points before the centre, past the centre before the last
# point, just past the last point, on the exit link; one northbound vehicle before its points
POSITIONS = [(EAST, 100.0, 10.0), (EAST, 147.0, 10.0), (EAST, 152.0, 10.0),
             (EAST, 157.0, 10.0), (EAST, 250.0, 10.0), (NORTH, 60.0, 10.0)]


@pytest.mark.parametrize(("population", "expected"), [
    ("conflict_ahead", [True, True, True, False, False, True]),
    ("before_last_centre", [True, True, False, False, False, True]),
    ("network", [True] * 6),
])
def test_population_on_a_constructed_state(population: str, expected: list[bool]) -> None:
    sim = hand_sim()
    place(sim, POSITIONS)
    assert cloud_population(sim.network, sim.view, population).tolist() == expected


def test_population_on_3x3_stops_at_the_last_intersection() -> None:
    # 3x3: the last conflict point of every lane is at 455 m, the last centre at 450 m
    sim = hand_sim(MiVeCCConfig())
    place(sim, [(0, 449.0, 10.0), (0, 452.0, 10.0), (0, 454.9, 10.0), (0, 455.0, 10.0),
                (7, 300.0, 10.0)])
    view = sim.view
    assert cloud_population(sim.network, view, "conflict_ahead").tolist() == [
        True, True, True, False, True]
    assert cloud_population(sim.network, view, "before_last_centre").tolist() == [
        True, False, False, False, True]


def test_cloud_graph_picks_only_the_population() -> None:
    sim = hand_sim(MiVeCCConfig(rows=1, cols=1, k_cloud=8))
    place(sim, POSITIONS)
    view = sim.view
    v = sim.v.ravel()[view.vehicle]
    a = sim.a.ravel()[view.vehicle]
    di = density_indicator(view, 5)
    for population, picked in (("conflict_ahead", {0, 1, 2, 5}), ("network", set(range(6)))):
        cfg = sim.config.replace(cloud_pick_population=population)
        g = cloud_graphs(sim.network, view, di, v, a, 1, cfg)
        assert set(g.view_index[0, 0][g.mask[0, 0] > 0].tolist()) == picked
        assert g.mask.sum() == len(picked)


@pytest.mark.parametrize("population", ["conflict_ahead", "before_last_centre", "network"])
def test_cloud_reward_over_the_same_population(population: str) -> None:
    env = mivecc_v0.parallel_env(rows=1, cols=1, density=1.0, scheme="EEC",
                                 cloud_pick_population=population)
    env.reset(seed=0)
    place(env.sim, [(EAST, 100.0, 8.0), (EAST, 140.0, 9.0), (EAST, 152.0, 12.0),
                    (EAST, 170.0, 13.0), (EAST, 250.0, 13.0)])
    env._observe()
    _, _, _, _, infos = env.step({})
    sim = env.sim
    s, v = sim.s[0, :5], sim.v[0, :5]
    assert sim.active[0, :5].all()
    last = {"conflict_ahead": 155.0, "before_last_centre": 150.0, "network": np.inf}[population]
    pop = s < last
    expected = float(np.mean(v[pop] - 12.0))
    assert infos["cloud_0"]["reward_velocity"] == pytest.approx(expected)
    assert int(infos["cloud_0"]["mask"].sum()) == int(pop.sum())


def test_unknown_population_is_rejected() -> None:
    with pytest.raises(ConfigError, match="cloud_pick_population"):
        MiVeCCConfig(cloud_pick_population="exit")
