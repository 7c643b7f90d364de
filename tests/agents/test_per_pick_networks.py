"""The ``per_pick`` network variant: one MLP shared by every column of the state graph."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mivecc_agents.networks import (
    PER_PICK_ACTOR_HIDDEN,
    PER_PICK_CRITIC_HIDDEN,
    PerPickActorNet,
    PerPickCriticNet,
    get_network_spec,
    make_actor_net,
    make_critic_net,
)
from tests.agents.tiny import TINY, train_tiny_edge

KINDS = ("edge", "cloud")


def _nets(kind: str, seed: int = 0) -> tuple[PerPickActorNet, PerPickCriticNet, int]:
    gen = torch.Generator().manual_seed(seed)
    actor = make_actor_net(kind, variant="per_pick", generator=gen)
    critic = make_critic_net(kind, variant="per_pick", generator=gen)
    return actor, critic, actor.spec.grid_size


def test_per_pick_spec_and_classes() -> None:
    for kind in KINDS:
        spec = get_network_spec(kind, "per_pick")
        assert spec.variant == "per_pick"
        assert spec.actor_hidden == PER_PICK_ACTOR_HIDDEN
        assert spec.critic_hidden == PER_PICK_CRITIC_HIDDEN
        assert spec.observation_shape == get_network_spec(kind).observation_shape
        actor, critic, k = _nets(kind)
        assert isinstance(actor, PerPickActorNet) and isinstance(critic, PerPickCriticNet)
        # one shared MLP: its input is one column (K rows x 3 channels), no convolution
        first = next(m for m in actor.mlp.modules() if isinstance(m, torch.nn.Linear))
        assert first.in_features == 3 * k
        assert not any(isinstance(m, torch.nn.Conv2d) for m in actor.modules())


@pytest.mark.parametrize("kind", KINDS)
def test_actor_is_permutation_equivariant_and_critic_invariant(kind: str) -> None:
    actor, critic, k = _nets(kind)
    gen = torch.Generator().manual_seed(3)
    obs = torch.rand(4, k, k, 3, generator=gen) * 2 - 1
    mask = torch.ones(4, k)
    mask[:, k - 3:] = 0
    perm = torch.randperm(k, generator=gen)
    action = actor(obs, mask)
    # columns are vehicles: permuting them permutes the actions and leaves the value
    torch.testing.assert_close(actor(obs[:, :, perm], mask[:, perm]), action[:, perm])
    torch.testing.assert_close(critic(obs[:, :, perm], action[:, perm], mask[:, perm]),
                               critic(obs, action, mask))


@pytest.mark.parametrize("kind", KINDS)
def test_a_vehicles_action_depends_only_on_its_own_column(kind: str) -> None:
    actor, _, k = _nets(kind)
    obs = torch.rand(2, k, k, 3, generator=torch.Generator().manual_seed(4))
    mask = torch.ones(2, k)
    changed = obs.clone()
    changed[:, :, 2] = -changed[:, :, 2]  # every row of column 2
    before, after = actor(obs, mask), actor(changed, mask)
    assert (before[:, 2] != after[:, 2]).all()
    others = [j for j in range(k) if j != 2]
    torch.testing.assert_close(before[:, others], after[:, others])


@pytest.mark.parametrize("kind", KINDS)
def test_critic_is_the_mean_of_per_column_terms(kind: str) -> None:
    _, critic, k = _nets(kind)
    gen = torch.Generator().manual_seed(5)
    obs = torch.rand(3, k, k, 3, generator=gen)
    action = 6 * torch.rand(3, k, generator=gen) - 3

    def value(columns: list[int]) -> torch.Tensor:
        mask = torch.zeros(3, k)
        mask[:, columns] = 1
        return critic(obs, action, mask)

    q0, q1, q4 = value([0]), value([1]), value([4])
    torch.testing.assert_close(value([0, 1, 4]), (q0 + q1 + q4) / 3)
    # no real column: value 0
    assert torch.equal(critic(obs, action, torch.zeros(3, k)), torch.zeros(3, 1))


def test_per_pick_training_writes_a_loadable_per_pick_policy(tmp_path) -> None:
    from mivecc_agents.checkpoints import load_checkpoint
    from mivecc_agents.policies import load_policy

    path = train_tiny_edge(tmp_path, TINY.replace(network="per_pick"))
    assert load_checkpoint(path)["network"] == "per_pick"
    policy = load_policy(path, expected_kind="edge")
    assert isinstance(policy.net, PerPickActorNet)
    obs = np.random.default_rng(0).uniform(-1, 1, (2, 15, 15, 3)).astype(np.float32)
    mask = np.ones((2, 15), np.float32)
    out = policy(obs, mask)
    assert out.shape == (2, 15) and np.abs(out).max() <= 3.0
    np.testing.assert_array_equal(out, policy(obs, mask))
