"""The TD3 option of the learner (``algorithm="td3"``): TorchRL's TD3Loss over two critics."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

pytest.importorskip("torchrl")

from mivecc_agents.checkpoints import load_checkpoint
from mivecc_agents.learner import DDPGLearner
from mivecc_agents.networks import make_actor, make_critic
from mivecc_agents.presets import get_preset, preset_with
from mivecc_agents.training import train
from tests.agents.tiny import TINY, train_tiny_edge

TD3 = TINY.replace(algorithm="td3", lr_actor=1e-2, lr_critic=1e-2)


def _buffer(k: int, n: int = 64) -> object:
    from tensordict import TensorDict
    from torchrl.data import LazyTensorStorage, ReplayBuffer

    gen = torch.Generator().manual_seed(1)
    data = TensorDict({
        ("edge", "observation"): torch.rand(n, k, k, 3, generator=gen),
        ("edge", "mask"): torch.ones(n, k),
        ("edge", "action"): 6 * torch.rand(n, k, generator=gen) - 3,
        ("next", "edge", "observation"): torch.rand(n, k, k, 3, generator=gen),
        ("next", "edge", "mask"): torch.ones(n, k),
        ("next", "edge", "reward"): torch.rand(n, 1, generator=gen),
        ("next", "edge", "done"): torch.zeros(n, 1, dtype=torch.bool),
        ("next", "edge", "terminated"): torch.zeros(n, 1, dtype=torch.bool),
    }, batch_size=[n])
    buffer = ReplayBuffer(storage=LazyTensorStorage(n), batch_size=32)
    buffer.extend(data)
    return buffer


def _td3_learner() -> DDPGLearner:
    torch.manual_seed(0)
    actor, critic = make_actor("edge", "edge"), make_critic("edge", "edge")
    return DDPGLearner(actor, critic, "edge", TD3, twin=make_critic("edge", "edge"))


def _flat(params: object) -> torch.Tensor:
    return torch.cat([p.detach().reshape(-1).clone() for p in params])


def test_td3_fields_and_their_errors() -> None:
    p = preset_with("released", {"algorithm": "td3", "td3_policy_delay": "3"})
    assert (p.algorithm, p.td3_policy_delay) == ("td3", 3)
    assert get_preset("released").algorithm == "ddpg"  # the presets keep DDPG
    assert (p.td3_target_noise, p.td3_noise_clip) == (0.6, 1.5)  # TD3's 0.2 / 0.5 of 3 m/s^2
    with pytest.raises(ValueError, match="td3_policy_delay"):
        TINY.replace(td3_policy_delay=0)
    with pytest.raises(ValueError, match="td3_target_noise"):
        TINY.replace(td3_target_noise=-0.1)
    with pytest.raises(ValueError, match=r"algorithm.*one of ddpg, td3"):
        preset_with("stable", {"algorithm": "sac"})


def test_td3_needs_a_twin_and_ddpg_refuses_one() -> None:
    actor, critic = make_actor("edge", "edge"), make_critic("edge", "edge")
    with pytest.raises(ValueError, match=r"twin.*second critic"):
        DDPGLearner(actor, critic, "edge", TD3)
    with pytest.raises(ValueError, match=r"twin.*no second critic"):
        DDPGLearner(actor, critic, "edge", TINY, twin=make_critic("edge", "edge"))


def test_td3_moves_the_actor_and_targets_every_second_update_only() -> None:
    learner = _td3_learner()
    buffer = _buffer(learner.actor.module.spec.grid_size)
    loss = learner.loss
    actor0 = _flat(learner.actor.parameters())
    target0 = _flat(loss.target_actor_network_params.values(True, True))
    critics0 = _flat(learner._critic_params)

    stats = learner.update(buffer, 1)  # update 1: critics only
    assert stats.n_updates == 1 and stats.actor_loss != stats.actor_loss  # NaN: no actor step
    assert torch.equal(_flat(learner.actor.parameters()), actor0)
    assert torch.equal(_flat(loss.target_actor_network_params.values(True, True)), target0)
    assert not torch.equal(_flat(learner._critic_params), critics0)

    stats = learner.update(buffer, 1)  # update 2: actor and targets too
    assert stats.actor_loss == stats.actor_loss
    assert not torch.equal(_flat(learner.actor.parameters()), actor0)
    assert not torch.equal(_flat(loss.target_actor_network_params.values(True, True)), target0)


def test_td3_critics_start_apart_and_the_checkpoint_critic_is_the_first() -> None:
    learner = _td3_learner()
    q = learner.loss.qvalue_network_params
    first, second = _flat(q[0].values(True, True)), _flat(q[1].values(True, True))
    assert not torch.equal(first, second)  # two initialisations: two estimates to take min of
    learner.update(_buffer(learner.actor.module.spec.grid_size), 4)
    state = learner.critic_state_dict()
    trained_first = _flat(learner.loss.qvalue_network_params[0].values(True, True))
    assert torch.equal(_flat(learner.critic.parameters()), trained_first)
    assert torch.equal(torch.cat([v.reshape(-1) for v in state.values()]),
                       _flat(learner.critic.module.parameters()))


def test_td3_training_run_saves_the_first_critic_and_resumes(tmp_path: Path) -> None:
    path = train_tiny_edge(tmp_path / "a", TD3)
    ck = load_checkpoint(path, expected_kind="edge")
    assert ck["preset"]["algorithm"] == "td3"
    prefix = "qvalue_network_params.module."  # the loss stacks the two critics: (2, ...)
    stacked = {k.removeprefix(prefix): v for k, v in ck["loss"].items() if k.startswith(prefix)}
    assert stacked.keys() == ck["critic"].keys()
    for name, value in ck["critic"].items():
        assert torch.equal(value, stacked[name][0]), name
        assert stacked[name].shape[0] == 2
    make_critic("edge", "edge").module.load_state_dict(ck["critic"])  # one network's weights
    new = train("edge", TD3, frames=300, rows=1, cols=1, densities=1500, seed=1,
                out_dir=tmp_path / "b", resume=path, progress=False)
    assert load_checkpoint(new)["updates"] > ck["updates"]
