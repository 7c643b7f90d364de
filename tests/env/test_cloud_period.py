"""A cloud that decides every n steps (config ``cloud_period``, mivecc_env.cloud_hold)."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.config import ConfigError, MiVeCCConfig

GRID = {"rows": 2, "cols": 2, "density": 1800, "scheme": "EEC"}


def _env(period: int, **kw) -> BatchedMiVeCCEnv:
    return BatchedMiVeCCEnv(batch_size=2, cloud_period=period, **{**GRID, **kw})


def _actions(env: BatchedMiVeCCEnv, value: float) -> np.ndarray:
    return np.full((env.batch_size, env.k_cloud), value)


def test_field_range():
    assert MiVeCCConfig().cloud_period == 1
    with pytest.raises(ConfigError, match=r"cloud_period: must be an integer in \[1, 1000\]"):
        MiVeCCConfig(cloud_period=0)


def test_decision_steps_every_period():
    env = _env(4)
    env.reset(seed=0)
    flags = []
    for _ in range(9):
        flags.append(env.cloud_decides.copy())
        env.step(None, _actions(env, 0.0))
    assert [bool(f[0]) for f in flags] == [True, False, False, False] * 2 + [True]
    env.reset_at([1])  # environment 1 restarts its own clock
    assert env.cloud_decides.tolist() == [False, True]


def test_actions_between_decisions_are_ignored():
    """Only the actions given on decision steps move the traffic."""
    runs = []
    for noise in (-3.0, 2.5):
        env = _env(5)
        env.reset(seed=7)
        for i in range(400):
            value = 1.0 if i % 5 == 0 else noise
            env.step(None, _actions(env, value))
        runs.append((env.sim.s.copy(), env.sim.v.copy()))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


def test_decision_actions_matter():
    out = []
    for value in (-3.0, 3.0):
        env = _env(5)
        env.reset(seed=7)
        for _ in range(400):
            env.step(None, _actions(env, value))
        out.append(env.summary()["mean_speed_mps"])
    assert np.all(out[1] > out[0])


def test_picked_vehicles_keep_their_command():
    """omega = 1: a held command is the executed acceleration of the vehicle it was for
    while that vehicle stays in the cloud's population; the others get none."""
    env = _env(4, omega=1.0)
    env.reset(seed=1)
    for _ in range(300):  # fill the network; the cloud commands nothing
        env.step(None, None)
    while not env.cloud_decides[0]:
        env.step(None, None)
    graphs = env._cloud  # the decision's columns -> vehicle slots
    slots, real = graphs.slot[:, 0], graphs.slot[:, 0] >= 0
    command = np.where(real, np.linspace(-0.9, 0.9, env.k_cloud)[None, :], 0.0)
    picked = slots[real]
    vid = env.sim.vid.ravel()[picked].copy()
    env.step(None, command)
    for _ in range(3):  # the held steps: these actions are ignored
        population = np.zeros(env.sim.vid.size, dtype=bool)  # before the step
        population[env.sim.view.vehicle[env._cloud_pop]] = True
        env.step(None, _actions(env, 3.0))
        a = env.sim.a.ravel()[picked]
        v = env.sim.v.ravel()[picked]
        c = env.config
        same = (env.sim.vid.ravel()[picked] == vid) & env.sim.active.ravel()[picked]
        free = same & population[picked] & (v > c.v_min_mps + 1e-9) & (v < c.v_max_mps - 1e-9)
        assert free.sum() > 10
        np.testing.assert_allclose(a[free], command[real][free], atol=1e-12)


def test_held_commands_follow_the_simulator_growing():
    """The simulator starts with few slots and adds more as the network fills."""
    env = BatchedMiVeCCEnv(batch_size=1, rows=3, cols=3, density=2100, scheme="EEC",
                           cloud_period=3)
    start = env.sim.active.shape[1]
    env.reset(seed=0)
    for _ in range(600):
        env.step(None, _actions(env, 1.0))
    assert env.sim.active.shape[1] > start
    assert env.summary()["in_network"][0] > 0
