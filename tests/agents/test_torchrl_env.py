"""The native batched TorchRL env (``MiVeCCTorchEnv``) against TorchRL's checks and the
PettingZooWrapper path."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from torchrl.envs import PettingZooWrapper, check_env_specs  # noqa: E402

from mivecc_agents.torchrl_env import MiVeCCTorchEnv  # noqa: E402
from mivecc_env import mivecc_v0  # noqa: E402
from mivecc_env.batched import REWARD_TERMS, BatchedMiVeCCEnv  # noqa: E402
from mivecc_env.metrics import SUMMARY_KEYS  # noqa: E402

CFG = {"rows": 1, "cols": 2, "scheme": "EEC", "max_steps": 6}


def _native(densities=(900.0, 1800.0, 2100.0), **kw) -> MiVeCCTorchEnv:
    return MiVeCCTorchEnv(densities=list(densities), **{**CFG, **kw})


def test_check_env_specs_both_groups_batch() -> None:
    env = _native(seed=0)
    assert env.batch_size == (3,)
    assert env.group_map == {"edge": ["edge_0", "edge_1"], "cloud": ["cloud_0"]}
    check_env_specs(env, seed=0)
    spec = env.full_observation_spec
    assert spec["edge", "observation"].shape == (3, 2, 15, 15, 3)
    assert spec["cloud", "observation"].shape == (3, 1, 60, 60, 3)
    assert spec["edge", "mask"].shape == (3, 2, 15)
    for key in REWARD_TERMS:
        assert spec["edge", "info", key].shape == (3, 2)
    for key in SUMMARY_KEYS:  # the summary lives in the cloud agent's info, as in the wrapper
        assert spec["cloud", "info", key].shape == (3, 1)
    assert not set(SUMMARY_KEYS) & set(spec["edge", "info"].keys())
    assert env.full_action_spec["cloud", "action"].shape == (3, 1, 60)


def test_edge_only_env_builds_no_cloud_graph() -> None:
    env = MiVeCCTorchEnv(densities=[900.0, 1500.0], rows=1, cols=1, scheme="EE", max_steps=5,
                         groups=("edge",), summary_keys=("collisions",), seed=1)
    check_env_specs(env)
    assert env.batched_env.observe == frozenset({"edge"})
    td = env.rollout(3)
    assert td["next", "edge", "info", "collisions"].shape == (2, 3, 1)
    assert td.get("cloud", None) is None


def test_observations_are_zero_copy_views() -> None:
    env = _native(seed=0)
    td = env.reset()
    obs = td["edge", "observation"]
    assert obs.dtype == torch.float32
    assert td["edge", "mask"].data_ptr() == td["edge", "info", "mask"].data_ptr()


def test_partial_reset_through_reset_key() -> None:
    env = _native(seed=3)
    td = env.reset()
    for _ in range(4):
        td["edge", "action"] = torch.zeros(3, 2, 15)
        td["cloud", "action"] = torch.zeros(3, 1, 60)
        td = env.step(td)["next"]
    before = td["edge", "observation"].clone()
    steps_before = env.batched_env.episode_steps.copy()
    assert steps_before.tolist() == [4, 4, 4]
    reset = torch.tensor([[True], [False], [True]])
    out = env.reset(td.set("_reset", reset))
    assert env.batched_env.episode_steps.tolist() == [0, 4, 0]
    # environment 1 keeps its state, the others restarted (an empty network at t = 0)
    torch.testing.assert_close(out["edge", "observation"][1], before[1], rtol=0, atol=0)
    assert out["cloud", "info", "sim_time_s"][:, 0].tolist() == pytest.approx([0.0, 0.4, 0.0])
    assert not out["done"].any()


def _actions(rng: np.random.Generator, n: int, shape: tuple[int, ...]) -> list[np.ndarray]:
    return [rng.uniform(-3, 3, shape).astype(np.float32) for _ in range(n)]


def test_same_observations_as_the_pettingzoo_wrapper() -> None:
    """Environment b of the native env seeded s is the wrapper's B = 1 env seeded s + b, over
    an automatic reset (max_steps 6, 9 steps)."""
    seed, steps = 11, 9
    dens = [1200.0, 2100.0]
    native = _native(densities=dens)
    native.set_seed(seed)
    rng = np.random.default_rng(0)
    edge_a = _actions(rng, steps, (2, 2, 15))
    cloud_a = _actions(rng, steps, (2, 1, 60))

    def run(env, b=None):
        out = []
        td = env.reset()
        for t in range(steps):
            ea, ca = edge_a[t], cloud_a[t]
            if b is not None:
                ea, ca = ea[b], ca[b]
            td["edge", "action"] = torch.from_numpy(ea)
            td["cloud", "action"] = torch.from_numpy(ca)
            full, td = env.step_and_maybe_reset(td)
            out.append(full.clone())
        return out

    got = run(native)
    for b, d in enumerate(dens):
        pz = PettingZooWrapper(mivecc_v0.parallel_env(density=d, **CFG),
                               categorical_actions=False)
        pz.set_seed(seed + b)
        ref = run(pz, b)
        for t in range(steps):
            for key in (("edge", "observation"), ("cloud", "observation"),
                        ("edge", "info", "mask"), ("cloud", "info", "mask")):
                torch.testing.assert_close(got[t][key][b], ref[t][key], rtol=0, atol=0,
                                           msg=f"{key} t={t} env={b}")
            for key in (("next", "edge", "observation"), ("next", "edge", "reward"),
                        ("next", "cloud", "reward"), ("next", "done"),
                        ("next", "cloud", "info", "avg_travel_velocity_mps")):
                torch.testing.assert_close(got[t][key][b], ref[t][key].to(got[t][key].dtype),
                                           rtol=0, atol=0, msg=f"{key} t={t} env={b}")


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="groups"):
        MiVeCCTorchEnv(groups=("bus",))
    with pytest.raises(ValueError, match="summary_keys"):
        MiVeCCTorchEnv(summary_keys=("speed",))
    with pytest.raises(ValueError, match=r"^densities: need at least one \[veh/lane/h\]"):
        MiVeCCTorchEnv(densities=[])
    with pytest.raises(ValueError, match=r"^raw_edge_period: must be an integer >= 0, got -1$"):
        MiVeCCTorchEnv(raw_edge_period=-1)


def test_a_missing_group_action_is_named() -> None:
    env = MiVeCCTorchEnv(densities=[900.0], rows=1, cols=1)
    td = env.reset()
    td["edge", "action"] = torch.zeros(1, 1, 15)
    with pytest.raises(KeyError, match=r"\('cloud', 'action'\): missing; the env's groups "
                       r"\['edge', 'cloud'\] each need an action at every step"):
        env.step(td)


SIGNAL_CFG = {"rows": 1, "cols": 2, "control": "signalized", "max_steps": 100,
              "signal_min_green_s": 1.0}


def test_signal_group_checks_its_specs_alone_and_with_the_coordinators() -> None:
    env = MiVeCCTorchEnv(densities=[1500.0, 2100.0], groups=("signal",), seed=0, **SIGNAL_CFG)
    check_env_specs(env, seed=0)
    assert env.group_map == {"signal": ["signal_0", "signal_1"]}
    assert env.batched_env.observe == frozenset()  # no coordinator graph is built
    spec = env.full_observation_spec
    assert spec["signal", "observation"].shape == (2, 2, 15)
    assert spec["signal", "info", "reward_pressure"].shape == (2, 2)
    assert spec["signal", "info", "throughput"].shape == (2, 2)  # the summary, here alone
    action = env.full_action_spec["signal", "action"]
    assert action.shape == (2, 2) and action.dtype == torch.int64 and action.space.n == 2
    both = MiVeCCTorchEnv(densities=[1500.0], groups=("edge", "signal"), seed=0, **SIGNAL_CFG)
    check_env_specs(both, seed=0)
    assert "throughput" not in both.full_observation_spec["signal", "info"]


def test_signal_group_equals_the_batched_env_with_its_phases() -> None:
    """The phases asked through the TorchRL env move the signals as the batched env's
    ``signal_action`` does: observations, rewards and terms equal, over a partial reset."""
    dens = [1500.0, 2400.0, 1800.0]
    native = MiVeCCTorchEnv(densities=dens, groups=("signal",), signal_reward="pressure",
                            **SIGNAL_CFG)
    native.set_seed(5)
    ref = BatchedMiVeCCEnv(batch_size=3, densities=dens, signal_agents=True,
                           signal_reward="pressure", **SIGNAL_CFG)
    rng = np.random.default_rng(2)
    td = native.reset()
    ref.reset(seed=5)  # set_seed's seeded reset; the collector's reset draws the next seeds
    out = ref.reset()
    phases_seen = set()
    for _ in range(150):
        np.testing.assert_array_equal(td["signal", "observation"].numpy(), out.signal_obs)
        phases = (rng.random((3, 2)) < 0.9).astype(np.int64)  # mostly north-south
        td["signal", "action"] = torch.from_numpy(phases)
        full, td = native.step_and_maybe_reset(td)
        out = ref.step(signal_action=phases)
        np.testing.assert_array_equal(full["next", "signal", "reward"][..., 0].numpy(),
                                      out.signal_reward.astype(np.float32))
        for key, value in out.signal_terms.items():
            np.testing.assert_array_equal(full["next", "signal", "info", key].numpy(),
                                          value.astype(np.float32))
        phases_seen |= set(out.signal_obs[..., 12].ravel().tolist())  # the current phase
        if out.truncated.any():
            out = ref.reset_at(np.flatnonzero(out.truncated))
    assert native.batched_env.episode_steps.tolist() == ref.episode_steps.tolist()
    assert phases_seen == {0.0, 1.0}  # the asked phases switched the signals


def test_signal_group_refused_without_signals_and_repeated_groups() -> None:
    from mivecc_env import ConfigError

    with pytest.raises(ConfigError, match=r"^signal_agents: only with control='signalized'"):
        MiVeCCTorchEnv(groups=("signal",), rows=1, cols=1)
    with pytest.raises(ValueError, match=r"^groups: must be a non-empty subset"):
        MiVeCCTorchEnv(groups=("edge", "edge"), rows=1, cols=1)
    env = MiVeCCTorchEnv(densities=[900.0], groups=("signal",), **SIGNAL_CFG)
    td = env.reset()
    with pytest.raises(KeyError, match=r"\('signal', 'action'\): missing"):
        env.step(td)
    td["signal", "action"] = torch.full((1, 2), 2)
    with pytest.raises(ValueError, match="signal"):
        env.step(td)
