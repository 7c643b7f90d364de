"""The critic ensemble of the learner (``critic_members``): DDPG with several critics."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch

pytest.importorskip("torchrl")

from mivecc_agents.checkpoints import load_checkpoint
from mivecc_agents.learner import DDPGLearner, make_loss
from mivecc_agents.networks import (
    CriticEnsembleNet,
    critic_members_in,
    make_actor,
    make_critic,
    make_critic_net,
)
from mivecc_agents.presets import get_preset, preset_with
from mivecc_agents.training import train
from tests.agents.test_td3 import _buffer
from tests.agents.tiny import TINY, train_tiny_edge

ENSEMBLE = TINY.replace(critic_members=3)


def test_critic_members_field_and_its_errors() -> None:
    assert get_preset("released").critic_members == 1  # the presets keep one critic
    assert preset_with("released", {"critic_members": "4"}).critic_members == 4
    for bad in (0, 17, 2.5):
        with pytest.raises(ValueError, match="critic_members"):
            TINY.replace(critic_members=bad)
    with pytest.raises(ValueError, match=r"critic_members: must be 1 with algorithm 'td3'"):
        TINY.replace(algorithm="td3", critic_members=2)


def test_ensemble_writes_one_value_per_member_from_its_own_weights() -> None:
    gen = torch.Generator().manual_seed(0)
    net = make_critic_net("edge", generator=gen, variant="released", members=3)
    assert isinstance(net, CriticEnsembleNet) and critic_members_in(net.state_dict()) == 3
    assert critic_members_in(make_critic_net("edge").state_dict()) == 1
    k = net.spec.grid_size
    obs, action, mask = torch.rand(5, k, k, 3), 6 * torch.rand(5, k) - 3, torch.ones(5, k)
    values = net(obs, action, mask)
    assert values.shape == (5, 3)
    for i, member in enumerate(net.members):
        assert torch.equal(values[:, i:i + 1], member(obs, action, mask))
    assert len(set(values[0].tolist())) == 3  # three initialisations, three estimates
    with pytest.raises(ValueError, match="members: an ensemble needs at least 2"):
        CriticEnsembleNet([make_critic_net("edge")])


def test_each_member_fits_its_own_target_and_the_actor_climbs_their_mean() -> None:
    """The ensemble's losses equal the mean of one-critic DDPG losses over each member (the
    same actor, each member with its own target copy), on the same minibatch."""
    torch.manual_seed(0)
    actor = make_actor("edge", "edge", variant="released")
    critic = make_critic("edge", "edge", variant="released", members=3)
    learner = DDPGLearner(actor, critic, "edge", ENSEMBLE.replace(network="released"))
    buffer = _buffer(actor.module.spec.grid_size)
    batch = buffer.sample()
    critic_loss, actor_loss, pred = learner._losses(batch, actor_step=True)
    assert pred.shape[-1] == 3

    singles = []
    for member in critic.module.members:
        one = copy.deepcopy(critic)
        one.module = copy.deepcopy(member)
        out = make_loss(copy.deepcopy(actor), one, "edge", ENSEMBLE.gamma)(batch.clone())
        singles.append((out["loss_value"], out["loss_actor"]))
    torch.testing.assert_close(critic_loss, torch.stack([s[0] for s in singles]).mean())
    torch.testing.assert_close(actor_loss, torch.stack([s[1] for s in singles]).mean())
    assert batch.get(("next", "edge", "reward")).shape[-1] == 1  # the sampled batch is kept


def test_ensemble_training_run_saves_every_member_and_resumes(tmp_path: Path) -> None:
    path = train_tiny_edge(tmp_path / "a", ENSEMBLE)
    ck = load_checkpoint(path, expected_kind="edge")
    assert ck["preset"]["critic_members"] == 3 and critic_members_in(ck["critic"]) == 3
    make_critic("edge", "edge", members=3).module.load_state_dict(ck["critic"])
    # resumed with a one-critic preset: the run goes on with the checkpoint's three critics
    new = train("edge", TINY, frames=300, rows=1, cols=1, densities=1500, seed=1,
                out_dir=tmp_path / "b", resume=path, progress=False)
    resumed = load_checkpoint(new)
    assert resumed["updates"] > ck["updates"]
    assert resumed["preset"]["critic_members"] == 3
