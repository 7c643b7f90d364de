"""API compliance of the MiVeCC environments: PettingZoo, Gymnasium, spaces, infos, actions."""

from __future__ import annotations

import functools
import importlib
import warnings
from collections.abc import Callable

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import api_test, parallel_api_test

import mivecc_env
from mivecc_env import CLOUD_AGENT, MiVeCCParallelEnv, mivecc_v0
from mivecc_env.metrics import SUMMARY_KEYS
from tests.env._pettingzoo_compat import run_parallel_seed_test

GYM_ID = "mivecc/MiVeCCEdge-v0"
TERMS = ("reward_sv", "reward_velocity", "reward_collision")
INFO_KEYS = {"mask", *TERMS}
# The whole-network node carries the episode summary (once per step, not once per agent).
CLOUD_INFO_KEYS = {*INFO_KEYS, *SUMMARY_KEYS}

Actions = dict[str, np.ndarray]
Policy = Callable[[MiVeCCParallelEnv, dict[str, dict], int], Actions]


def small_env(**kw: object) -> MiVeCCParallelEnv:
    """A 1 x 2 grid with enough traffic to fill the control areas within 150 steps."""
    args: dict[str, object] = {"rows": 1, "cols": 2, "density": 1800, "max_steps": 150}
    args.update(kw)
    return mivecc_v0.parallel_env(**args)


def random_policy(seed: int) -> Policy:
    """Uniform actions in each agent's box from one seeded generator."""
    rng = np.random.default_rng(seed)

    def act(env: MiVeCCParallelEnv, infos: dict[str, dict], t: int) -> Actions:
        del infos, t
        return {
            a: rng.uniform(-1, 1, env.action_space(a).shape).astype(np.float32)
            * env.config.a_max_mps2
            for a in env.agents
        }

    return act


def rollout(
    env: MiVeCCParallelEnv, policy: Policy, seed: int, steps: int
) -> list[tuple[dict, dict]]:
    """(observations, rewards) of every step, reset included (rewards empty there)."""
    obs, infos = env.reset(seed=seed)
    out = [(obs, {})]
    for t in range(steps):
        if not env.agents:
            break
        obs, rewards, _, _, infos = env.step(policy(env, infos, t))
        out.append((obs, rewards))
    return out


def same_trajectory(a: list[tuple[dict, dict]], b: list[tuple[dict, dict]]) -> bool:
    """Equal observations (bit for bit) and rewards at every step."""
    if len(a) != len(b):
        return False
    for (obs_a, rew_a), (obs_b, rew_b) in zip(a, b, strict=True):
        if obs_a.keys() != obs_b.keys() or rew_a != rew_b:
            return False
        if not all(np.array_equal(obs_a[k], obs_b[k]) for k in obs_a):
            return False
    return True


# --------------------------------------------------------------------------------------------
# PettingZoo
def test_parallel_api_test() -> None:
    parallel_api_test(small_env(max_steps=60), num_cycles=100)


def test_parallel_api_test_3x3() -> None:
    env = mivecc_v0.parallel_env(rows=3, cols=3, density=1800, max_steps=30)
    parallel_api_test(env, num_cycles=40)
    assert env.possible_agents == [*(f"edge_{i}" for i in range(9)), "cloud_0"]


def test_parallel_seed_test() -> None:
    run_parallel_seed_test(functools.partial(small_env, max_steps=40), num_cycles=50)


def test_aec_api_test() -> None:
    with warnings.catch_warnings():
        # api_test's advice on graph-shaped, signed, all-zero observations does not apply.
        warnings.simplefilter("ignore", UserWarning)
        api_test(mivecc_v0.env(rows=1, cols=1, density=1800, max_steps=40), num_cycles=60)


def test_truncation_after_max_steps() -> None:
    env = small_env(max_steps=5)
    env.reset(seed=0)
    agents = list(env.possible_agents)
    for t in range(1, 6):
        obs, rewards, terms, truncs, infos = env.step({})
        for d in (obs, rewards, terms, truncs, infos):
            assert list(d) == agents
        assert not any(terms.values())
        assert all(truncs.values()) == (t == 5)
        assert any(truncs.values()) == (t == 5)
    assert env.agents == []
    env.reset(seed=1)
    assert env.agents == agents


@pytest.mark.parametrize(("rows", "cols"), [(1, 1), (1, 2), (2, 3)])
def test_agent_names(rows: int, cols: int) -> None:
    env = mivecc_v0.parallel_env(rows=rows, cols=cols)
    names = [f"edge_{i}" for i in range(rows * cols)] + ["cloud_0"]
    assert env.possible_agents == names
    assert env.agents == []
    env.reset(seed=0)
    assert env.agents == names
    assert env.agents is not env.possible_agents


# --------------------------------------------------------------------------------------------
# Spaces, observations, infos
def test_spaces_are_cached_float32_boxes() -> None:
    env = mivecc_v0.parallel_env(rows=2, cols=2)
    a_max = env.config.a_max_mps2
    for agent in env.possible_agents:
        k = 60 if agent == CLOUD_AGENT else 15
        obs_space, act_space = env.observation_space(agent), env.action_space(agent)
        assert env.observation_space(agent) is obs_space
        assert env.action_space(agent) is act_space
        assert isinstance(obs_space, gymnasium.spaces.Box)
        assert isinstance(act_space, gymnasium.spaces.Box)
        assert obs_space.dtype == np.float32 and act_space.dtype == np.float32
        assert obs_space.shape == (k, k, 3) and act_space.shape == (k,)
        assert np.all(obs_space.low == -1) and np.all(obs_space.high == 1)
        assert np.all(act_space.low == -a_max) and np.all(act_space.high == a_max)


def test_custom_k_sizes_the_spaces() -> None:
    env = mivecc_v0.parallel_env(rows=1, cols=1, k_edge=4, k_cloud=7)
    assert env.observation_space("edge_0").shape == (4, 4, 3)
    assert env.action_space("cloud_0").shape == (7,)


def test_rollout_observations_and_infos() -> None:
    env = small_env(max_steps=60)
    obs, infos = env.reset(seed=3)
    policy = random_policy(3)
    filled = 0.0
    for t in range(61):
        assert list(obs) == list(infos) == env.possible_agents
        for agent in env.possible_agents:
            space = env.observation_space(agent)
            o, info = obs[agent], infos[agent]
            assert o.dtype == np.float32 and o.shape == space.shape
            assert space.contains(o)
            assert set(info) == (CLOUD_INFO_KEYS if agent == CLOUD_AGENT else INFO_KEYS)
            mask = info["mask"]
            assert mask.dtype == np.float32 and mask.shape == (space.shape[0],)
            assert set(np.unique(mask)) <= {0.0, 1.0}
            # Real columns come first and padded columns are all zero.
            assert np.all(np.diff(mask) <= 0)
            assert not np.any(o[:, mask == 0, :])
            filled += mask.sum()
            for key in set(info) - {"mask"}:
                assert isinstance(info[key], float)
        if t == 60:
            break
        obs, rewards, terms, _, infos = env.step(policy(env, infos, t))
        assert not any(terms.values())
        for agent, reward in rewards.items():
            assert isinstance(reward, float)
            terms_sum = sum(infos[agent][key] for key in TERMS)
            assert reward == pytest.approx(terms_sum, rel=1e-12, abs=1e-12)
        assert infos[CLOUD_AGENT]["reward_sv"] == 0.0
    assert filled > 0, "no vehicle was ever observed: the checks above were vacuous"
    assert not env.agents


def test_state_is_the_cloud_graph() -> None:
    env = small_env()
    obs, _ = env.reset(seed=0)
    for _ in range(20):
        obs, *_ = env.step({})
    state = env.state()
    assert np.array_equal(state, obs[CLOUD_AGENT])
    assert state is not obs[CLOUD_AGENT]


# --------------------------------------------------------------------------------------------
# Determinism
def test_same_seed_same_trajectory() -> None:
    a = rollout(small_env(), random_policy(7), seed=11, steps=60)
    b = rollout(small_env(), random_policy(7), seed=11, steps=60)
    assert same_trajectory(a, b)


def test_different_seed_different_trajectory() -> None:
    a = rollout(small_env(), random_policy(7), seed=11, steps=60)
    b = rollout(small_env(), random_policy(7), seed=12, steps=60)
    assert not same_trajectory(a, b)


def test_unseeded_reset_continues_the_seeded_sequence() -> None:
    def two_episodes() -> list:
        env = small_env(max_steps=30)
        first = rollout(env, random_policy(0), seed=5, steps=30)
        obs, _ = env.reset()
        second = [(obs, {})]
        for _ in range(30):
            obs, rewards, *_ = env.step({})
            second.append((obs, rewards))
        return [first, second]

    a, b = two_episodes(), two_episodes()
    assert same_trajectory(a[0], b[0]) and same_trajectory(a[1], b[1])
    assert not same_trajectory(a[0][:31], a[1])


# --------------------------------------------------------------------------------------------
# Actions
def _constant(edge: float, cloud: float) -> Policy:
    def act(env: MiVeCCParallelEnv, infos: dict[str, dict], t: int) -> Actions:
        del infos, t
        return {
            a: np.full(env.action_space(a).shape, cloud if a == CLOUD_AGENT else edge, np.float32)
            for a in env.agents
        }

    return act


def test_padded_columns_are_ignored() -> None:
    base = random_policy(1)
    noise = np.random.default_rng(2)
    cache: dict[int, Actions] = {}

    def real_part(env: MiVeCCParallelEnv, infos: dict[str, dict], t: int) -> Actions:
        if t not in cache:
            cache[t] = base(env, infos, t)
        return cache[t]

    def padded_changed(env: MiVeCCParallelEnv, infos: dict[str, dict], t: int) -> Actions:
        actions = {a: x.copy() for a, x in real_part(env, infos, t).items()}
        for agent, x in actions.items():
            pad = infos[agent]["mask"] == 0
            x[pad] = noise.uniform(-3, 3, int(pad.sum()))
        return actions

    a = rollout(small_env(scheme="EEC"), real_part, seed=4, steps=150)
    b = rollout(small_env(scheme="EEC"), padded_changed, seed=4, steps=150)
    assert same_trajectory(a, b)
    # ... while the real columns' actions do change it (the check above is not vacuous).
    zero = rollout(small_env(scheme="EEC"), _constant(0.0, 0.0), seed=4, steps=150)
    assert not same_trajectory(a, zero)


def test_scheme_e_ignores_actions() -> None:
    a = rollout(small_env(scheme="E"), random_policy(0), seed=2, steps=150)
    b = rollout(small_env(scheme="E"), _constant(0.0, 0.0), seed=2, steps=150)
    c = rollout(small_env(scheme="E"), lambda env, infos, t: {}, seed=2, steps=150)
    assert same_trajectory(a, b) and same_trajectory(a, c)


def test_scheme_ee_uses_edge_actions_only() -> None:
    # The edge action wins only where it agrees in sign with the rule and is larger
    # (``max(a_edge, a_end)``), so a full positive action is the one that shows.
    zero = rollout(small_env(scheme="EE"), _constant(0.0, 0.0), seed=2, steps=150)
    edge = rollout(small_env(scheme="EE"), _constant(3.0, 0.0), seed=2, steps=150)
    cloud = rollout(small_env(scheme="EE"), _constant(0.0, -3.0), seed=2, steps=150)
    assert not same_trajectory(zero, edge)
    assert same_trajectory(zero, cloud)


def test_scheme_eec_uses_cloud_actions() -> None:
    zero = rollout(small_env(scheme="EEC"), _constant(0.0, 0.0), seed=2, steps=150)
    cloud = rollout(small_env(scheme="EEC"), _constant(0.0, -3.0), seed=2, steps=150)
    assert not same_trajectory(zero, cloud)


def test_actions_reach_their_columns_vehicles() -> None:
    env = small_env(scheme="EEC")
    env.reset(seed=0)
    for _ in range(100):
        env.step({})
    rng = np.random.default_rng(0)
    actions = {a: rng.uniform(-3, 3, env.action_space(a).shape) for a in ("edge_1", "cloud_0")}
    edge_cmd, cloud_cmd = env._commands(actions)
    for cmd, slots, act in (
        (edge_cmd, env._edge.slot[0, 1], actions["edge_1"]),
        (cloud_cmd, env._cloud.slot[0, 0], actions["cloud_0"]),
    ):
        real = slots >= 0
        assert real.any()
        np.testing.assert_array_equal(cmd.ravel()[slots[real]], act[real])
        assert np.isnan(cmd).sum() == cmd.size - real.sum()  # edge_0 sent nothing
    assert np.isnan(edge_cmd.ravel()[env._edge.slot[0, 0][env._edge.slot[0, 0] >= 0]]).all()


def test_box_edges_accepted() -> None:
    env = small_env(scheme="EEC")
    env.reset(seed=0)
    for value in (-3.0, 3.0):
        env.step({a: np.full(env.action_space(a).shape, value, np.float32) for a in env.agents})
    env.step({a: env.action_space(a).high.astype(np.float64).tolist() for a in env.agents})


# --------------------------------------------------------------------------------------------
# Gymnasium
def test_gymnasium_registered_once() -> None:
    assert GYM_ID in gymnasium.registry
    assert [k for k in gymnasium.registry if k.startswith("mivecc/")] == [GYM_ID]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mivecc_env.register_gymnasium()
        importlib.reload(mivecc_env)
    assert [k for k in gymnasium.registry if k.startswith("mivecc/")] == [GYM_ID]


def test_gymnasium_check_env() -> None:
    env = gymnasium.make(GYM_ID, rows=1, cols=1, density=900, max_steps=200)
    with warnings.catch_warnings():
        # The action box is in m/s^2, not normalised: check_env's advice, not an error.
        warnings.filterwarnings("ignore", message=".*symmetric and normalized space.*")
        check_env(env.unwrapped)
    env.close()


def test_gymnasium_edge_matches_parallel_env() -> None:
    kw = {"rows": 1, "cols": 2, "density": 1800, "max_steps": 50, "scheme": "EE"}
    gym_env = gymnasium.make(GYM_ID, intersection=1, **kw)
    par_env = mivecc_v0.parallel_env(**kw)
    obs, info = gym_env.reset(seed=9)
    pobs, pinfos = par_env.reset(seed=9)
    assert np.array_equal(obs, pobs["edge_1"])
    rng = np.random.default_rng(0)
    for t in range(50):
        action = rng.uniform(-3, 3, 15).astype(np.float32)
        obs, reward, term, trunc, info = gym_env.step(action)
        pobs, prew, pterm, ptrunc, pinfos = par_env.step({"edge_1": action})
        assert np.array_equal(obs, pobs["edge_1"])
        assert reward == prew["edge_1"]
        assert not term and not pterm["edge_1"]
        assert trunc == (t == 49) == ptrunc["edge_1"]
        assert np.array_equal(info["mask"], pinfos["edge_1"]["mask"])


def test_returned_observations_and_infos_are_not_changed_by_later_steps() -> None:
    """Observations and masks are views of each step's fresh arrays and every action goes
    through the fast (one concatenation) path here: what a step returned stays as it was."""
    env = small_env(scheme="EEC")
    obs, infos = env.reset(seed=3)
    policy = random_policy(3)
    kept = []
    for t in range(60):
        actions = policy(env, infos, t)
        assert env._every_column(actions) is not None  # the one-concatenation path
        obs, rewards, _, _, infos = env.step(actions)
        if t % 10 == 9:
            snapshot = ({a: o.copy() for a, o in obs.items()},
                        {a: {k: np.array(v, copy=True) for k, v in i.items()}
                         for a, i in infos.items()}, dict(rewards))
            kept.append(((obs, infos, rewards), snapshot))
    assert any(float(i["mask"].sum()) > 0 for i in infos.values())
    for (obs, infos, rewards), (obs0, infos0, rewards0) in kept:
        assert all(np.array_equal(obs[a], obs0[a]) for a in obs0)
        assert all(np.array_equal(infos[a][k], infos0[a][k], equal_nan=True)
                   for a in infos0 for k in infos0[a])
        assert rewards == rewards0
