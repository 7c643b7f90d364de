"""The MiVeCC ParallelEnv under TorchRL's PettingZooWrapper (groups ``edge`` and ``cloud``)."""

from __future__ import annotations

import warnings

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from torchrl.envs import PettingZooWrapper, SerialEnv  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from mivecc_env import mivecc_v0  # noqa: E402
from mivecc_env.metrics import SUMMARY_KEYS  # noqa: E402

pytestmark = pytest.mark.filterwarnings(
    "ignore:PettingZoo in TorchRL is tested using version:UserWarning"
)

ROWS, COLS = 1, 2
N_EDGE = ROWS * COLS
GROUPS = {"edge": [f"edge_{i}" for i in range(N_EDGE)], "cloud": ["cloud_0"]}
TERMS = ("reward_sv", "reward_velocity", "reward_collision")


def make_env(max_steps: int = 40, group_map: dict | None = GROUPS) -> PettingZooWrapper:
    penv = mivecc_v0.parallel_env(
        rows=ROWS, cols=COLS, density=1800, max_steps=max_steps, scheme="EEC"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return PettingZooWrapper(penv, group_map=group_map, categorical_actions=False)


def test_check_env_specs() -> None:
    env = make_env()
    check_env_specs(env, seed=0)
    env.close()


def test_group_map() -> None:
    env = make_env()
    assert env.group_map == GROUPS
    # Without a group map the wrapper groups by name prefix, which gives the same groups.
    default = make_env(group_map=None)
    assert dict(default.group_map) == GROUPS


def test_specs() -> None:
    env = make_env()
    obs = env.observation_spec
    assert obs["edge", "observation"].shape == (N_EDGE, 15, 15, 3)
    assert obs["cloud", "observation"].shape == (1, 60, 60, 3)
    assert obs["edge", "observation"].dtype == torch.float32
    assert obs["edge", "info", "mask"].shape == (N_EDGE, 15)
    assert obs["cloud", "info", "mask"].shape == (1, 60)
    for key in TERMS:
        assert obs["edge", "info", key].shape == (N_EDGE,)
    for key in (*TERMS, *SUMMARY_KEYS):
        assert obs["cloud", "info", key].shape == (1,)
    assert not set(SUMMARY_KEYS) & set(obs["edge", "info"].keys())
    act = env.full_action_spec
    assert act["edge", "action"].shape == (N_EDGE, 15)
    assert act["cloud", "action"].shape == (1, 60)
    assert act["edge", "action"].dtype == torch.float32
    assert torch.all(act["edge", "action"].space.high == 3.0)
    assert torch.all(act["cloud", "action"].space.low == -3.0)
    assert set(env.reward_keys) == {("edge", "reward"), ("cloud", "reward")}


def test_rollout_shapes_and_mask() -> None:
    env = make_env()
    env.set_seed(0)
    td = env.rollout(30)
    assert td.batch_size == (30,)
    nxt = td["next"]
    assert nxt["edge", "observation"].shape == (30, N_EDGE, 15, 15, 3)
    assert nxt["cloud", "observation"].shape == (30, 1, 60, 60, 3)
    assert nxt["edge", "reward"].shape == (30, N_EDGE, 1)
    assert nxt["cloud", "done"].shape == (30, 1, 1)
    mask = nxt["edge", "info", "mask"]
    assert mask.shape == (30, N_EDGE, 15) and mask.dtype == torch.float32
    cloud_mask = nxt["cloud", "info", "mask"]
    assert cloud_mask.shape == (30, 1, 60)
    assert cloud_mask.sum() > 0
    # Padded columns (mask 0) are all-zero columns of the state graph.
    obs = nxt["cloud", "observation"]  # (T, 1, K, K, 3): rows, columns, channels
    padded = (cloud_mask == 0)[:, :, None, :, None].expand_as(obs)
    assert torch.all(obs[padded] == 0)
    # The reward is the sum of its named terms.
    terms = sum(nxt["edge", "info", key] for key in TERMS)
    torch.testing.assert_close(nxt["edge", "reward"].squeeze(-1), terms)


def test_truncation_and_auto_reset() -> None:
    env = make_env(max_steps=4)
    env.set_seed(1)
    td = env.rollout(10, break_when_any_done=False)
    truncated = td["next", "truncated"].squeeze(-1)
    assert truncated.tolist() == [
        False,
        False,
        False,
        True,
        False,
        False,
        False,
        True,
        False,
        False,
    ]
    assert td["next", "edge", "truncated"].squeeze(-1)[3].all()
    assert not td["next", "edge", "terminated"].any()
    sim_time = td["next", "cloud", "info", "sim_time_s"][:, 0]
    torch.testing.assert_close(sim_time[:5], torch.tensor([0.1, 0.2, 0.3, 0.4, 0.1]))


def test_batched_serial_env() -> None:
    env = SerialEnv(2, make_env)
    check_env_specs(env, seed=0)
    td = env.rollout(3)
    assert td["edge", "observation"].shape == (2, 3, N_EDGE, 15, 15, 3)
    assert td["next", "cloud", "info", "mask"].shape == (2, 3, 1, 60)
    env.close()


def test_seeded_rollouts_repeat() -> None:
    def run() -> torch.Tensor:
        env = make_env()
        env.set_seed(5)
        torch.manual_seed(5)
        return env.rollout(20)["next", "cloud", "observation"]

    assert torch.equal(run(), run())
