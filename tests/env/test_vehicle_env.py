"""The vehicle-agent envs (``mivecc_vehicles_v0``): PettingZoo's API tests (parallel and AEC),
agents that come and go, determinism, CoMADDPG's evaluation reproduced through both, and bad
input."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test

from mivecc_env import mivecc_vehicles_v0
from mivecc_env.config import ConfigError


def _env(**kw):
    return mivecc_vehicles_v0.parallel_env(**{"rows": 1, "cols": 1, "density": 1500,
                                              "max_steps": 400, **kw})


def test_pettingzoo_parallel_api() -> None:
    with warnings.catch_warnings():
        # possible_agents bounds the vehicles of an episode; most never come
        warnings.filterwarnings("ignore", message="No agents present but not all")
        parallel_api_test(_env(rows=2, cols=2, density=900), num_cycles=500)


def test_pettingzoo_aec_api() -> None:
    for density, max_steps in ((300, 300), (2100, 150)):
        api_test(mivecc_vehicles_v0.env(rows=2, cols=2, density=density, max_steps=max_steps),
                 num_cycles=1000)


def test_aec_episode_without_any_agent_ends_at_reset() -> None:
    par = mivecc_vehicles_v0.parallel_env(rows=2, cols=2, density=300, max_steps=100)
    par.reset(seed=0)  # no vehicle reaches a control area within 100 steps
    assert par.agents == []
    env = mivecc_vehicles_v0.env(rows=2, cols=2, density=300, max_steps=100)
    env.reset(seed=0)
    assert env.agents == [] and list(env.agent_iter()) == []
    with pytest.raises(ValueError, match="seed"):  # the parallel env's own errors still raise
        env.reset(seed=-1)
    env.reset(seed=1)  # and the next episode runs
    assert env.agents == ["vehicle_0"]


def _rollout(env, seed: int, accel: float = 1.0) -> list[tuple]:
    obs, _ = env.reset(seed=seed)
    trace, live = [], set(env.agents)
    assert env.agents and set(obs) == live  # the rules ran until a vehicle is in an area
    while env.agents:
        for agent in env.agents:
            assert env.observation_space(agent).contains(obs[agent])
        actions = {a: np.array([accel], np.float32) for a in env.agents}
        obs, rewards, terminated, truncated, infos = env.step(actions)
        assert set(rewards) == set(terminated) == set(truncated) == set(obs) == set(infos)
        assert live <= set(obs)  # every agent that acted gets its last entries
        ended = {a for a in live if terminated[a] or truncated[a]}
        assert not ended & set(env.agents)  # an agent that ended does not come back
        live = set(env.agents)
        trace.append((tuple(sorted(rewards.items())), tuple(sorted(terminated.items()))))
    return trace


def test_agents_come_and_go_and_runs_repeat() -> None:
    env = _env()
    first = _rollout(env, 3)
    assert any(any(t for _, t in step[1]) for step in first)  # vehicles left their area
    assert first == _rollout(env, 3)
    assert first != _rollout(env, 4)
    summary = env.summary()
    assert summary["throughput"] > 0


def test_the_shipped_comaddpg_policy_runs_as_in_its_evaluation() -> None:
    from mivecc_agents.comaddpg import SHIPPED_PATH, CoMADDPGPolicy
    from mivecc_agents.evaluation import evaluate_scheme

    policy = CoMADDPGPolicy.load(SHIPPED_PATH)
    env = _env(max_steps=1000)
    obs, _ = env.reset(seed=1)
    while env.agents:
        names = list(env.agents)
        accel = policy(np.stack([obs[a] for a in names]))
        obs, *_ = env.step({a: np.array([x], np.float32) for a, x in
                            zip(names, np.clip(accel, -3.0, 3.0), strict=True)})
    ref = evaluate_scheme("comaddpg", 1, 1, 1500, 1000, 1, progress=False,
                          policies={"vehicle": policy})
    for key in ("avg_travel_velocity_mps", "throughput", "collisions", "mean_speed_mps"):
        assert env.summary()[key] == ref[key], key


def test_aec_env_runs_the_parallel_trajectory() -> None:
    # Every live vehicle acts once per cycle; those that join act from the next cycle.
    def policy(obs: np.ndarray) -> np.ndarray:
        return np.array([np.tanh(4 * obs[1, 0] - obs[0, 1]) * 3.0], np.float32)

    kw = {"rows": 2, "cols": 2, "density": 1500, "max_steps": 300}
    par = mivecc_vehicles_v0.parallel_env(**kw)
    obs, _ = par.reset(seed=2)
    expected = [(a, 0.0) for a in par.agents]  # the AEC env shows 0 at the first turn
    while par.agents:
        obs, rewards, *_ = par.step({a: policy(obs[a]) for a in par.agents})
        expected += rewards.items()
    aec = mivecc_vehicles_v0.env(**kw)
    aec.reset(seed=2)
    shown = []
    for agent in aec.agent_iter():
        obs_a, reward, terminated, truncated, _ = aec.last()
        shown.append((agent, reward))
        aec.step(None if terminated or truncated else policy(obs_a))
    assert aec.unwrapped.summary() == par.summary()
    assert len(expected) > 1000 and sorted(shown) == sorted(expected)


def test_aec_env_checks_an_action_when_it_is_given() -> None:
    env = mivecc_vehicles_v0.env(rows=1, cols=1, density=1500, max_steps=200)
    env.reset(seed=0)
    agent = env.agent_selection
    for bad in ([4.0], [np.nan], [0.0, 1.0], "fast"):
        with pytest.raises(ValueError, match=rf"actions\['{agent}'\]: must be one finite"):
            env.step(bad)
        assert env.agent_selection == agent  # the turn is not taken


def test_bad_input_is_refused_with_the_field_or_agent_named() -> None:
    for kw, message in (({"k": 1}, r"k: must be an integer in \[2, 64\]"),
                        ({"render_mode": "human"}, "render_mode: mivecc_vehicles_v0 has none"),
                        ({"safety_weight": -1.0}, "safety_weight: must be a finite number"),
                        ({"control": "signalized"}, "control: vehicle agents need"),
                        ({"model": "released"}, "model: vehicle agents need model='paper'"),
                        ({"min_headway_s": 0.0}, "min_headway_s: must be > 0"),
                        ({"density": -5}, "density")):
        with pytest.raises(ConfigError, match=message):
            _env(**kw)
    env = _env(max_steps=120)
    with pytest.raises(RuntimeError, match="call reset"):
        env.step({})
    env.reset(seed=0)
    while env.agents:
        env.step({a: [0.0] for a in env.agents})
    with pytest.raises(RuntimeError, match="the episode has ended"):
        env.step({})
    env.reset(seed=0)
    agent = env.agents[0]
    for actions, message in (({}, f"no action for live agent '{agent}'"),
                             ({agent: [0.0], "vehicle_999": [0.0]}, "'vehicle_999' is not a live"),
                             ({agent: [4.0]}, rf"actions\['{agent}'\]: must be one finite"),
                             ({agent: [np.nan]}, "must be one finite"),
                             ({agent: [0.0, 1.0]}, "must be one finite"),
                             ([0.0], "actions: expected a dict")):
        with pytest.raises(ValueError, match=message):
            env.step(actions)
    while len(env.agents) < 3:
        env.step({a: 0.5 for a in env.agents})  # scalars are accepted
    import torch  # a tensor that requires grad is taken by its values, as in the other envs

    env.step({a: torch.tensor([0.5], requires_grad=True) for a in env.agents})
    last = env.agents[-1]
    for bad in ([np.nan], [3.5], [[0.0]], "fast", [0.0, 0.0]):
        actions = {a: np.zeros(1, np.float32) for a in env.agents}
        actions[last] = bad  # the one bad action among good ones is named
        with pytest.raises(ValueError, match=rf"actions\['{last}'\]: must be one finite"):
            env.step(actions)
