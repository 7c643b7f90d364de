"""``gymnasium.make_vec("mivecc/MiVeCCEdge-v0", vectorization_mode="vector_entry_point")``."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import mivecc_env  # registers the gymnasium id
from mivecc_env.single_agent import MiVeCCEdgeVectorEnv

GYM_ID = "mivecc/MiVeCCEdge-v0"
KW = {"rows": 1, "cols": 2, "density": 1800, "max_steps": 25, "intersection": 1}


def make(mode: str, n: int) -> gymnasium.vector.VectorEnv:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return gymnasium.make_vec(GYM_ID, num_envs=n, vectorization_mode=mode, **KW)


def test_make_vec_gives_the_batched_vector_env() -> None:
    env = make("vector_entry_point", 3)
    assert isinstance(env.unwrapped, MiVeCCEdgeVectorEnv)
    assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert env.num_envs == 3
    assert env.observation_space.shape == (3, 15, 15, 3)
    assert env.action_space.shape == (3, 15)
    assert env.single_observation_space.dtype == np.float32
    obs, infos = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert infos["mask"].shape == (3, 15) and infos["_mask"].all()
    obs, rew, term, trunc, infos = env.step(env.action_space.sample())
    assert obs.shape == (3, 15, 15, 3) and rew.shape == term.shape == trunc.shape == (3,)
    with pytest.raises(ValueError, match=r"actions: .*\(3, 15\)"):
        env.step(np.zeros((2, 15)))


def test_same_trajectory_as_sync_vector_env_with_autoreset() -> None:
    # Three episodes of 25 steps: the next-step autoresets (and their seeds) must match
    # gymnasium's own SyncVectorEnv of the single-agent env, bit for bit.
    n = 3
    vec, sync = make("vector_entry_point", n), make("sync", n)
    o1, i1 = vec.reset(seed=7)
    o2, i2 = sync.reset(seed=7)
    rng = np.random.default_rng(0)
    ends = 0
    for t in range(80):
        assert np.array_equal(o1, o2), t
        assert np.array_equal(i1["mask"], i2["mask"]), t
        act = rng.uniform(-3, 3, (n, 15)).astype(np.float32)
        o1, r1, te1, tr1, i1 = vec.step(act)
        o2, r2, te2, tr2, i2 = sync.step(act)
        assert np.array_equal(r1, r2) and np.array_equal(te1, te2), t
        assert np.array_equal(tr1, tr2), t
        for key in ("reward_sv", "reward_velocity", "reward_collision"):
            assert np.array_equal(i1[key], i2[key]), (t, key)
        ends += int(tr1.sum())
    assert ends == 3 * n
    vec.close()
    sync.close()


def test_unseeded_reset_and_per_env_densities() -> None:
    env = MiVeCCEdgeVectorEnv(num_envs=2, densities=[600.0, 3000.0], rows=1, cols=1,
                              max_steps=400)
    env.reset(seed=3)
    for _ in range(300):
        env.step(np.zeros((2, 15), np.float32))
    arrived = env.summary()["arrived"]
    assert arrived[1] > 2 * arrived[0]  # the demands differ per copy
    with pytest.raises(mivecc_env.ConfigError, match="intersection"):
        MiVeCCEdgeVectorEnv(num_envs=2, intersection=1, rows=1, cols=1)


def test_copies_and_seeds_are_named() -> None:
    for bad in (0, -1, 1.5, True):
        with pytest.raises(mivecc_env.ConfigError, match=rf"^num_envs: must be an integer >= 1, "
                           rf"got {bad}$"):
            MiVeCCEdgeVectorEnv(num_envs=bad)  # type: ignore[arg-type]
    env = MiVeCCEdgeVectorEnv(num_envs=2, rows=1, cols=1)
    with pytest.raises(ValueError, match=r"^seed: need one seed per environment \(2\), got 1$"):
        env.reset(seed=[1])
    with pytest.raises(ValueError, match=r"^seed: must be None, an integer >= 0"):
        env.reset(seed=["a", "b"])
