"""Signal agents (``signal_agents=True``): spaces, bounds, timing, defaults, bad input, APIs."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test

from mivecc_env import mivecc_v0
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.config import ConfigError
from mivecc_env.signal_agents import OBS_DIM, OBS_FEATURES, SIGNAL_REWARD_TERMS

KW = {"rows": 1, "cols": 2, "density": 1800, "control": "signalized"}


def parallel(**kw):
    return mivecc_v0.parallel_env(**(KW | {"signal_agents": True} | kw))


def test_flag_needs_signalized_control_and_valid_options() -> None:
    with pytest.raises(ConfigError, match=r"signal_agents.*signalized"):
        mivecc_v0.parallel_env(rows=1, cols=1, signal_agents=True)
    with pytest.raises(ConfigError, match=r"signal_agents.*signalized"):
        BatchedMiVeCCEnv(rows=1, cols=1, control="reservation", signal_agents=True)
    with pytest.raises(ConfigError, match="signal_agents: must be True or False"):
        BatchedMiVeCCEnv(**KW, signal_agents="yes")
    with pytest.raises(ConfigError, match="signal_reward"):
        parallel(signal_reward="delay")
    for name in ("queue", "pressure", "throughput"):
        assert parallel(signal_reward=name).batched.signal_reward == name


def test_agents_and_spaces() -> None:
    env = parallel()
    assert env.possible_agents == ["edge_0", "edge_1", "cloud_0", "signal_0", "signal_1"]
    assert env.action_space("signal_1").n == 2
    space = env.observation_space("signal_0")
    assert space.shape == (OBS_DIM,) == (15,) and space.dtype == np.float32
    assert OBS_FEATURES[:3] == ("east_approaching", "east_queue", "east_mean_speed_mps")
    assert OBS_FEATURES[-3:] == ("phase", "stage", "elapsed_s")
    obs, infos = env.reset(seed=0)
    assert set(obs) == set(infos) == set(env.possible_agents)
    assert set(infos["signal_0"]) == set(SIGNAL_REWARD_TERMS)
    # Without the flag, nothing changes for the coordinators.
    assert mivecc_v0.parallel_env(**KW).possible_agents == ["edge_0", "edge_1", "cloud_0"]


def test_pettingzoo_api_tests_with_signal_agents() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        parallel_api_test(parallel(max_cycles=60), num_cycles=80)
        api_test(mivecc_v0.env(**KW, signal_agents=True, max_cycles=30), num_cycles=40)


def _random_run(steps: int, seed: int, reward: str = "queue"):
    """(obs, terms, rewards) per step of a batched run under random phase actions."""
    env = BatchedMiVeCCEnv(rows=1, cols=2, density=2400, control="signalized",
                           max_steps=steps, batch_size=3, signal_agents=True,
                           signal_reward=reward, observe=())
    rng = np.random.default_rng(seed)
    out = env.reset(seed=seed)
    history = [out]
    for _ in range(steps):
        out = env.step(signal_action=rng.integers(-1, 2, size=(3, 2)))
        history.append(out)
    return env, history


def test_observation_in_bounds_and_timing_enforced_under_random_actions() -> None:
    penv = parallel(density=2400, max_cycles=1500)
    space = penv.observation_space("signal_0")
    env, history = _random_run(1500, seed=3)
    c = env.config
    obs = np.stack([h.signal_obs for h in history])  # (T, B, n_int, D)
    assert obs.dtype == np.float32
    assert (obs >= space.low).all() and (obs <= space.high).all()
    assert obs[..., 1].max() > 0  # queues did form: the bound was exercised
    phase, stage, elapsed = obs[..., -3].astype(int), obs[..., -2].astype(int), obs[..., -1]
    changed = stage[1:] != stage[:-1]
    prev_stage, new_stage = stage[:-1][changed], stage[1:][changed]
    duration = elapsed[:-1][changed] + c.dt_s  # how long the stage that ended lasted [s]
    # Stages run green -> yellow -> all-red -> green, with the enforced durations.
    assert ((new_stage - prev_stage) % 3 == 1).all()
    greens = duration[prev_stage == 0]
    assert greens.size > 20 and greens.min() >= c.signal_min_green_s - 1e-6
    assert greens.min() < c.signal_green_s  # the agents, not the fixed plan, ended greens
    np.testing.assert_allclose(duration[prev_stage == 1], c.signal_yellow_s, atol=1e-6)
    np.testing.assert_allclose(duration[prev_stage == 2], c.signal_all_red_s, atol=1e-6)
    # The phase flips exactly when the all-red ends.
    flips = phase[1:] != phase[:-1]
    assert (flips == (changed & (stage[1:] == 0))).all()
    # Rewards: the chosen term; queue = -(queued vehicles on the four approaches).
    for h in history[1:]:
        np.testing.assert_array_equal(h.signal_reward, h.signal_terms["reward_queue"])
        queued = h.signal_obs[..., [1, 4, 7, 10]].sum(axis=-1)
        np.testing.assert_array_equal(h.signal_terms["reward_queue"], -queued)
    assert (history[0].signal_reward == 0).all()


def test_pressure_reward() -> None:
    _, history = _random_run(200, seed=1, reward="pressure")
    for h in history[1:]:
        np.testing.assert_array_equal(h.signal_reward, h.signal_terms["reward_pressure"])
    assert min(h.signal_reward.min() for h in history) < 0


@pytest.mark.parametrize("grid", [1, 3])
def test_throughput_reward_counts_every_centre_crossing(grid: int) -> None:
    """Summed over a run from an empty network, the vehicles that passed each centre are those
    that left the network (each passed every centre of its lane) plus those still in it past
    that centre (no collisions under signals)."""
    env = BatchedMiVeCCEnv(batch_size=3, densities=[600, 1500, 2100], control="signalized",
                           signal_agents=True, signal_reward="throughput", observe=(),
                           rows=grid, cols=grid, max_steps=1500)
    out = env.reset(seed=4)
    assert (out.signal_reward == 0).all()
    total = np.zeros((3, grid * grid))
    for _ in range(1500):
        out = env.step()
        np.testing.assert_array_equal(out.signal_reward, out.signal_terms["reward_throughput"])
        total += out.signal_reward
    sim, net = env.sim, env.sim.network
    assert env.summary()["collisions"].sum() == 0
    passed = (sim.s[..., None] >= net.lane_centres_s[sim.lane]) & sim.active[..., None]
    inter = net.lane_intersections[sim.lane]
    still_in = np.zeros_like(total)
    for b in range(3):
        np.add.at(still_in[b], inter[b][passed[b]], 1)
    exited = env.summary()["throughput"]  # every exited vehicle passed `grid` centres
    assert total.sum() > 100
    np.testing.assert_array_equal(total.sum(axis=1), grid * exited + still_in.sum(axis=1))
    if grid == 1:
        np.testing.assert_array_equal(total[:, 0], exited + still_in[:, 0])


def test_no_action_is_the_fixed_time_trajectory() -> None:
    plain = mivecc_v0.parallel_env(**KW, max_cycles=700)
    agents = parallel(max_cycles=700)
    partial = parallel(max_cycles=700)
    for env in (plain, agents, partial):
        env.reset(seed=5)
    for t in range(700):
        o1, r1, *_ = plain.step({})
        o2, r2, *_ = agents.step({})
        # signal_1 always asks for the phase that is green: same as fixed-time only if the
        # plan would not switch, so only signal_0 (left out) is compared below.
        partial.step({"signal_1": int(partial.sim.signal_phases.phase[0, 1])})
        for a in plain.possible_agents if plain.agents else []:
            np.testing.assert_array_equal(o1[a], o2[a])
            assert r1[a] == r2[a]
        if t % 50 == 0:
            np.testing.assert_array_equal(plain.sim.s, agents.sim.s)
            np.testing.assert_array_equal(plain.sim.v, agents.sim.v)
            for name in ("phase", "stage", "elapsed"):
                a = getattr(plain.sim.signal_phases, name)
                np.testing.assert_array_equal(a, getattr(agents.sim.signal_phases, name))
                np.testing.assert_array_equal(a[:, 0], getattr(partial.sim.signal_phases,
                                                               name)[:, 0])
    # signal_1 held its green: it never switched, while signal_0 followed the plan.
    assert partial.sim.signal_phases.elapsed[0, 1] > 600
    # All -1 in the batched env is the same as no action.
    b1 = BatchedMiVeCCEnv(**KW, signal_agents=True)
    b2 = BatchedMiVeCCEnv(**KW, signal_agents=True)
    b1.reset(seed=2)
    b2.reset(seed=2)
    for _ in range(400):
        x, y = b1.step(), b2.step(signal_action=np.full((1, 2), -1))
    np.testing.assert_array_equal(x.signal_obs, y.signal_obs)
    np.testing.assert_array_equal(x.edge_obs, y.edge_obs)


def test_batch_matches_single_runs() -> None:
    rng = np.random.default_rng(0)
    acts = rng.integers(-1, 2, size=(300, 2, 2))
    batch = BatchedMiVeCCEnv(**KW, batch_size=2, signal_agents=True)
    batch.reset(seed=10)
    singles = [BatchedMiVeCCEnv(**KW, signal_agents=True) for _ in range(2)]
    for b, env in enumerate(singles):
        env.reset(seed=10 + b)
    for t in range(300):
        out = batch.step(signal_action=acts[t])
        for b, env in enumerate(singles):
            one = env.step(signal_action=acts[t, b:b + 1])
            np.testing.assert_array_equal(out.signal_obs[b], one.signal_obs[0])
            np.testing.assert_array_equal(out.signal_reward[b], one.signal_reward[0])


@pytest.mark.parametrize("action", [2, -1, 1.0, "0", np.array([0, 1]), None, True])
def test_bad_agent_action_names_the_agent(action) -> None:
    env = parallel()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions\['signal_1'\].*Discrete\(2\)"):
        env.step({"signal_0": 0, "signal_1": action})


def test_numpy_integer_actions_accepted() -> None:
    env = parallel()
    env.reset(seed=0)
    env.step({"signal_0": np.int64(1), "signal_1": np.array(0)})


@pytest.mark.parametrize(
    ("action", "match"),
    [(np.zeros((1, 3), dtype=int), "shape"), (np.zeros((1, 2)), "dtype"),
     (np.full((1, 2), 2), "range")],
)
def test_bad_batched_action(action, match: str) -> None:
    env = BatchedMiVeCCEnv(**KW, signal_agents=True)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=f"signal_action.*{match}"):
        env.step(signal_action=action)


def test_batched_action_needs_the_flag() -> None:
    env = BatchedMiVeCCEnv(**KW)
    env.reset(seed=0)
    assert env.step().signal_obs is None
    with pytest.raises(ValueError, match="signal_action: needs signal_agents=True"):
        env.step(signal_action=np.zeros((1, 2), dtype=int))


def test_reset_at_keeps_the_signal_rewards_of_the_others() -> None:
    env = BatchedMiVeCCEnv(**KW, batch_size=2, signal_agents=True)
    env.reset(seed=0)
    for _ in range(300):
        last = env.step()
    out = env.reset_at([0])
    assert (out.signal_reward[0] == 0).all()
    np.testing.assert_array_equal(out.signal_reward[1], last.signal_reward[1])
    np.testing.assert_array_equal(out.signal_terms["reward_pressure"][1],
                                  last.signal_terms["reward_pressure"][1])


def test_torchrl_wrapper_builds_the_signal_group() -> None:
    torch = pytest.importorskip("torch")
    pytest.importorskip("torchrl")
    from torchrl.envs import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        env = PettingZooWrapper(parallel(max_steps=40), categorical_actions=True)
    assert set(env.group_map) == {"edge", "cloud", "signal"}
    assert env.observation_spec["signal", "observation"].shape == (2, OBS_DIM)
    check_env_specs(env, seed=0)
    td = env.rand_step(env.reset(seed=0))
    assert td["next", "signal", "reward"].shape == (2, 1)
    assert td["next", "signal", "reward"].dtype == torch.float32
    env.close()
