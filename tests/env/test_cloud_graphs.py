"""``cloud_graphs="per_lane"``: the paper's Algorithm 1 cloud, one K x K graph per through lane.

What it must do: each lane's graph holds that lane's highest-DI vehicles of the cloud's
population (and only them); the shapes follow in every API; the batch gives each environment's
single run bit for bit; and the cloud's actions reach exactly the vehicles it picked (a constant
cloud acting per lane moves the traffic exactly as one network graph that picks every vehicle).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mivecc_env import mivecc_v0
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.sim.state_graph import cloud_population
from mivecc_env.sim.virtual_lane import density_indicator
from tests.env.test_batched import run_against_singles

PER_LANE = {"scheme": "EEC", "cloud_graphs": "per_lane"}


def test_shapes_follow_the_option() -> None:
    net = MiVeCCConfig(rows=3, cols=3)
    assert (net.n_cloud_graphs, net.cloud_graph_shape, net.cloud_action_shape) == (
        1, (60, 60, 3), (60,))
    lane = MiVeCCConfig(rows=1, cols=2, k_cloud=8, cloud_graphs="per_lane")
    assert (lane.n_cloud_graphs, lane.cloud_graph_shape, lane.cloud_action_shape) == (
        6, (6, 8, 8, 3), (6, 8))
    with pytest.raises(ConfigError, match=r"cloud_graphs: must be one of \['network',"):
        MiVeCCConfig(cloud_graphs="lanes")


def _picks_by_lane(env: BatchedMiVeCCEnv) -> list[set[int]]:
    """Vehicle ids in each lane graph's real columns (environment 0)."""
    graphs, sim = env._cloud, env.sim
    vid = sim.vid.ravel()
    return [set(vid[graphs.slot[0, lane][graphs.mask[0, lane] > 0]].tolist())
            for lane in range(graphs.slot.shape[1])]


def test_each_lane_graph_holds_that_lanes_highest_di_vehicles() -> None:
    k = 4  # fewer than a busy lane holds: the selection, not just the population, is tested
    env = BatchedMiVeCCEnv(batch_size=1, rows=2, cols=2, density=2100, k_cloud=k, **PER_LANE)
    env.reset(seed=3)
    full_lanes = 0
    for _ in range(250):
        env.step(None, np.zeros((1, *env.cloud_action_shape)))
    sim, graphs = env.sim, env._cloud
    view = sim.view  # the default model's cloud view is the edges' (the released one: below)
    di = density_indicator(view, env.config.di_n)
    pop = cloud_population(sim.network, view, env.config.cloud_pick_population)
    vid = sim.vid.ravel()[view.vehicle]
    picks = _picks_by_lane(env)
    assert graphs.obs.shape == (1, 8, k, k, 3)
    for lane, picked in enumerate(picks):
        on_lane = np.flatnonzero(pop & (view.lane == lane))
        order = on_lane[np.argsort(-di[on_lane], kind="stable")]
        assert picked == set(vid[order[:k]].tolist()), lane
        full_lanes += len(on_lane) > k
    assert full_lanes >= 2  # some lanes held more than K eligible vehicles


def test_large_k_per_lane_picks_the_whole_population_once() -> None:
    env = BatchedMiVeCCEnv(batch_size=1, rows=3, cols=3, density=1500, **PER_LANE)
    env.reset(seed=1)
    for _ in range(300):
        out = env.step(None, np.zeros((1, *env.cloud_action_shape)))
    picks = _picks_by_lane(env)
    sim = env.sim
    pop = env._cloud_pop
    assert out.cloud_mask.shape == (1, 12, 60)
    assert sum(map(len, picks)) == int(pop.sum()) == int(out.cloud_mask.sum()) > 50
    union = set().union(*picks)
    assert union == set(sim.vid.ravel()[sim.view.vehicle[pop]].tolist())


@pytest.mark.parametrize("model", ["paper", "released"])
def test_constant_cloud_per_lane_equals_one_graph_of_every_vehicle(model: str) -> None:
    """Per lane (K = 60 a lane) and one network graph with K = 512 pick the same vehicles here
    (no lane holds 60): with the same constant action the runs are identical."""
    kw = {"rows": 3, "cols": 3, "density": 2100, "scheme": "EEC", "model": model}
    runs = []
    for extra in ({"cloud_graphs": "per_lane"}, {"k_cloud": 512}):
        env = BatchedMiVeCCEnv(batch_size=1, **kw, **extra)
        env.reset(seed=2)
        for _ in range(400):
            out = env.step(np.zeros((1, env.n_edge, env.k_edge)),
                           np.full((1, *env.cloud_action_shape), 3.0))
        runs.append((env.sim.s.copy(), env.sim.v.copy(), out.cloud_mask.sum()))
    (x1, v1, n1), (x2, v2, n2) = runs
    assert n1 == n2 > 100
    assert np.array_equal(x1, x2) and np.array_equal(v1, v2)
    # and the cloud's action matters: without it the traffic is elsewhere
    env = BatchedMiVeCCEnv(batch_size=1, **kw, cloud_graphs="per_lane")
    env.reset(seed=2)
    for _ in range(400):
        env.step(np.zeros((1, env.n_edge, env.k_edge)), np.zeros((1, *env.cloud_action_shape)))
    assert not np.array_equal(env.sim.v, v1)


def test_batch_matches_single_runs() -> None:
    kw = {"rows": 2, "cols": 2, "max_steps": 1000, "k_cloud": 6, **PER_LANE}
    seen = run_against_singles(kw, [4, 9, 0], [900.0, 2100.0, 1500.0], steps=120,
                               resets={60: [1]})
    assert seen > 500


def test_parallel_env_spaces_actions_and_errors() -> None:
    env = mivecc_v0.parallel_env(rows=1, cols=2, density=1800, k_cloud=8, **PER_LANE)
    obs, infos = env.reset(seed=0)
    assert env.observation_space("cloud_0").shape == obs["cloud_0"].shape == (6, 8, 8, 3)
    assert env.action_space("cloud_0").shape == infos["cloud_0"]["mask"].shape == (6, 8)
    assert env.state_space.shape == env.state().shape == (6, 8, 8, 3)
    for _ in range(100):
        acts = {a: env.action_space(a).sample() for a in env.agents}
        obs, *_ , infos = env.step(acts)
    assert infos["cloud_0"]["mask"].sum() > 0
    with pytest.raises(ValueError, match=r"actions\['cloud_0'\]"):
        env.step({"cloud_0": np.zeros(8, np.float32)})
    bad = np.zeros((6, 8), np.float32)
    bad[np.unravel_index(np.argmax(infos["cloud_0"]["mask"]), bad.shape)] = np.nan
    with pytest.raises(ValueError, match=r"actions\['cloud_0'\]"):
        env.step({"cloud_0": bad})


def test_pettingzoo_parallel_and_aec_api() -> None:
    from pettingzoo.test import api_test, parallel_api_test

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # image-like observation advice
        parallel_api_test(mivecc_v0.parallel_env(rows=1, cols=2, density=1800, k_cloud=8,
                                                 max_cycles=40, **PER_LANE), num_cycles=50)
        parallel_api_test(mivecc_v0.parallel_env(rows=2, cols=1, density=1800, model="released",
                                                 cloud_period=5, max_cycles=40, **PER_LANE),
                          num_cycles=50)
        api_test(mivecc_v0.env(rows=1, cols=1, density=1800, k_cloud=4, max_cycles=30,
                               **PER_LANE), num_cycles=40)


def test_torchrl_env_has_one_cloud_agent_per_lane() -> None:
    torch = pytest.importorskip("torch")
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs

    from mivecc_agents.torchrl_env import MiVeCCTorchEnv

    cfg = MiVeCCConfig(rows=1, cols=2, density_vplh=1800, k_cloud=8, max_steps=50, **PER_LANE)
    env = MiVeCCTorchEnv(2, config=cfg, seed=0)
    check_env_specs(env)
    assert env.group_map["cloud"] == [f"cloud_{i}" for i in range(6)]
    td = env.rollout(30)
    assert td["cloud", "observation"].shape == (2, 30, 6, 8, 8, 3)
    reward = td["next", "cloud", "reward"]
    assert reward.shape == (2, 30, 6, 1)
    assert torch.equal(reward, reward[:, :, :1].expand_as(reward))  # the network's reward
