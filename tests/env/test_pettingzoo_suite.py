"""PettingZoo's own test suite (``pettingzoo.test``) on both environments, and what it needs:
``state_space``, ``max_cycles``, ``render_mode="human"`` (headless: Agg).

Not run: ``manual_control_test`` (keyboard games) and ``bombardment_test``, which fails on
PettingZoo's own ``generated_agents_env_v0`` too (it checks the ``None`` that ``env.step``
returns as an observation); ``test_observation_bounds.py`` does that check properly.
"""

from __future__ import annotations

import functools
import types
import warnings

import matplotlib
import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    performance_benchmark,
    render_test,
    seed_test,
    state_test,
)
from pettingzoo.test import test_save_obs as save_obs_check  # (not collected by pytest)

from mivecc_env import mivecc_edges_v0, mivecc_v0
from mivecc_env.config import ConfigError
from mivecc_env.render import render_rgb
from tests.env._pettingzoo_compat import run_parallel_seed_test

MODULES = {"mivecc_v0": mivecc_v0, "mivecc_edges_v0": mivecc_edges_v0}
SMALL = {"rows": 1, "cols": 2, "density": 1800}


def small(module: types.ModuleType) -> types.ModuleType:
    """``module`` with a small grid by default (max_cycles_test builds envs from the module)."""
    return types.SimpleNamespace(
        parallel_env=functools.partial(module.parallel_env, **SMALL),
        env=functools.partial(module.env, **SMALL),
    )


@pytest.fixture(autouse=True)
def _headless_and_quiet():
    matplotlib.use("Agg")
    with warnings.catch_warnings():
        # api_test / state_test advise on image-like (K, K, 3) signed observations: not images.
        warnings.simplefilter("ignore", UserWarning)
        yield


@pytest.mark.parametrize("name", MODULES)
def test_pettingzoo_suite(name: str) -> None:
    mod = small(MODULES[name])
    parallel_api_test(mod.parallel_env(max_cycles=60), num_cycles=80)
    api_test(mod.env(max_cycles=30), num_cycles=40)
    run_parallel_seed_test(functools.partial(mod.parallel_env, max_cycles=40), num_cycles=50)
    seed_test(functools.partial(mod.env, max_cycles=30), num_cycles=40)
    max_cycles_test(mod)
    render_test(mod.env)
    state_test(mod.env(max_cycles=30), mod.parallel_env(max_cycles=30), num_cycles=20)
    env = mod.env(max_cycles=10)
    env.reset(seed=0)
    save_obs_check(env)


@pytest.mark.slow
def test_performance_benchmark_runs() -> None:
    performance_benchmark(mivecc_v0.env(**SMALL, max_cycles=100))


def test_state_space_holds_the_state() -> None:
    env = mivecc_v0.parallel_env(**SMALL, max_cycles=50)
    assert env.state_space.shape == (60, 60, 3) and env.state_space.dtype == np.float32
    env.reset(seed=1)
    while env.agents:
        assert env.state_space.contains(env.state())
        env.step({})


def test_max_cycles_is_max_steps() -> None:
    env = mivecc_v0.parallel_env(max_cycles=7)
    assert env.config.max_steps == 7
    with pytest.raises(ConfigError, match=r"max_cycles.*max_steps"):
        mivecc_v0.parallel_env(max_cycles=7, max_steps=8)


def test_human_render_draws_the_frame_headless() -> None:
    env = mivecc_v0.parallel_env(**SMALL, max_cycles=30, render_mode="human")
    env.reset(seed=0)
    for _ in range(25):
        env.step({})  # human mode draws every step (Gymnasium's convention)
    assert env.render() is None
    viewer = env._viewer
    assert viewer.frames_shown == 27  # reset + 25 steps + the explicit render
    shown = np.asarray(viewer.figure.axes[0].images[0].get_array())
    assert np.array_equal(shown, render_rgb(env.sim, 0))
    assert shown.any()
    env.close()
    assert viewer.figure is None


def test_unknown_render_mode_rejected() -> None:
    with pytest.raises(ConfigError, match="render_mode"):
        mivecc_v0.parallel_env(render_mode="ansi")
