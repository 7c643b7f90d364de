"""The edge-only view (homogeneous edge agents, no cloud_0) and the PettingZoo registry."""

from __future__ import annotations

import pickle

import numpy as np
import pettingzoo
import pytest
from pettingzoo.test import api_test, parallel_api_test

import mivecc_env
from mivecc_env import CLOUD_AGENT, mivecc_edges_v0, mivecc_v0
from mivecc_env.config import ConfigError
from tests.env._pettingzoo_compat import run_parallel_seed_test

KW = {"rows": 1, "cols": 2, "density": 1800, "max_steps": 40}


def test_agents_are_homogeneous_edges() -> None:
    env = mivecc_edges_v0.parallel_env(rows=2, cols=2)
    assert env.possible_agents == [f"edge_{i}" for i in range(4)]
    first = env.possible_agents[0]
    for a in env.possible_agents:
        assert env.observation_space(a) == env.observation_space(first)
        assert env.action_space(a) == env.action_space(first)
    assert env.state_space.shape == (60, 60, 3)
    assert env.config.scheme == "EE"


def test_pettingzoo_api_and_seed_tests() -> None:
    parallel_api_test(mivecc_edges_v0.parallel_env(**KW), num_cycles=60)
    run_parallel_seed_test(lambda: mivecc_edges_v0.parallel_env(**KW), num_cycles=30)
    api_test(mivecc_edges_v0.env(**KW), num_cycles=30)


def test_edges_match_the_full_env() -> None:
    kw = {**KW, "max_steps": 150}
    view = mivecc_edges_v0.parallel_env(scheme="EE", **kw)
    full = mivecc_v0.parallel_env(scheme="EE", **kw)
    obs, infos = view.reset(seed=3)
    fobs, finfos = full.reset(seed=3)
    rng = np.random.default_rng(0)
    seen = 0.0
    while view.agents:
        for a in view.agents:
            assert np.array_equal(obs[a], fobs[a])
            assert np.array_equal(infos[a]["mask"], finfos[a]["mask"])
            seen += infos[a]["mask"].sum()
        acts = {a: rng.uniform(-3, 3, 15).astype(np.float32) for a in view.agents}
        obs, rew, _, trunc, infos = view.step(acts)
        fobs, frew, _, ftrunc, finfos = full.step(acts)
        assert CLOUD_AGENT not in obs and CLOUD_AGENT not in rew
        assert rew == {a: frew[a] for a in rew}
        assert trunc == {a: ftrunc[a] for a in trunc}
    assert np.array_equal(view.state(), full.state())
    assert seen > 0, "no vehicle observed: the comparison was vacuous"
    assert not full.agents


def test_cloud_action_and_eec_rejected() -> None:
    env = mivecc_edges_v0.parallel_env(**KW)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="no agent 'cloud_0'"):
        env.step({CLOUD_AGENT: np.zeros(60, np.float32)})
    with pytest.raises(ConfigError, match="scheme"):
        mivecc_edges_v0.parallel_env(scheme="EEC")


def test_copies_made_before_the_first_reset_see_different_traffic() -> None:
    # SuperSuit's concat_vec_envs_v1 pickles the env: unseeded copies must not be clones.
    env = mivecc_edges_v0.parallel_env(**KW)
    a, b = pickle.loads(pickle.dumps(env)), pickle.loads(pickle.dumps(env))
    a.reset()
    b.reset()
    for _ in range(40):
        a.step({})
        b.step({})
    assert a.summary() != b.summary()
    # ... and a seeded reset is the same as the full env's.
    c = pickle.loads(pickle.dumps(env))
    c.reset(seed=5)
    full = mivecc_v0.parallel_env(scheme="EE", **KW)
    full.reset(seed=5)
    assert np.array_equal(c.state(), full.state())


@pytest.mark.skipif(not hasattr(pettingzoo, "register"), reason="PettingZoo < 1.27: no registry")
def test_registered_with_pettingzoo() -> None:
    for env_id, cls in (("mivecc/mivecc-v0", mivecc_env.MiVeCCParallelEnv),
                        ("mivecc/mivecc_edges-v0", mivecc_env.MiVeCCEdgesParallelEnv)):
        par = pettingzoo.make("parallel", env_id, rows=1, cols=2)
        assert type(par) is cls and par.config.cols == 2
        aec = pettingzoo.make("aec", env_id, rows=1, cols=1)
        assert isinstance(aec, pettingzoo.AECEnv)
        assert aec.possible_agents == par.possible_agents[:1] + par.possible_agents[2:]
    par = pettingzoo.make("parallel", "mivecc/mivecc_vehicles-v0", rows=1, cols=2, k=4)
    assert type(par).__name__ == "MiVeCCVehiclesParallelEnv" and par.k == 4
    aec = pettingzoo.make("aec", "mivecc/mivecc_vehicles-v0", rows=1, cols=1)
    assert isinstance(aec, pettingzoo.AECEnv) and aec.possible_agents[0] == "vehicle_0"
    assert mivecc_env.register_pettingzoo() is True  # idempotent: no override warning


def test_env_side_imports_no_torch() -> None:
    # A BenchMARL user installs mivecc without the train extra (BenchMARL pins torchrl < 0.12).
    import subprocess
    import sys

    code = (
        "import sys, mivecc_env, mivecc_env.mivecc_v0, mivecc_env.mivecc_edges_v0, "
        "mivecc_env.mivecc_vehicles_v0, "
        "mivecc_env.single_agent, mivecc_env.render\n"
        "top = {m.split('.')[0] for m in sys.modules}\n"
        "bad = sorted(top & {'torch', 'torchrl', 'tensordict'})\n"
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
