"""Tests of the MiVeCC actor and critic networks (paper Table "HyperParameter")."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from mivecc_agents.networks import (
    ACTION_SCALE_MPS2,
    ACTOR_FINAL_INIT_BOUND,
    CLOUD_SPEC,
    EDGE_SPEC,
    NETWORK_SPECS,
    NetworkSpec,
    count_parameters,
    get_network_spec,
    make_actor,
    make_actor_net,
    make_critic,
    make_critic_net,
)

KINDS = ("edge", "cloud")
VARIANTS = ("paper", "released", "per_pick")
LEADING_DIMS = ((), (4,), (2, 9))


def _observation(spec: NetworkSpec, batch: tuple[int, ...], seed: int = 0) -> torch.Tensor:
    """Random channel-last state graphs ``(*batch, K, K, 3)``."""
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(*batch, *spec.observation_shape, generator=gen)


def _mask(spec: NetworkSpec, batch: tuple[int, ...], n_real: int) -> torch.Tensor:
    """Float mask ``(*batch, K)`` whose first ``n_real`` columns are real vehicles."""
    mask = torch.zeros(*batch, spec.action_dim)
    mask[..., :n_real] = 1.0
    return mask


# --------------------------------------------------------------------------------------------
# Specs and parameter counts
# --------------------------------------------------------------------------------------------


def test_specs_match_paper_table() -> None:
    assert EDGE_SPEC.observation_shape == (15, 15, 3)
    assert EDGE_SPEC.n_convs == 2
    assert EDGE_SPEC.conv_output_shape == (16, 3, 3)  # 15 -> 7 -> 3
    assert EDGE_SPEC.flattened_size == 144
    assert EDGE_SPEC.actor_layers == (96, 96, 15)
    assert EDGE_SPEC.critic_layers == (96, 96, 48, 12, 1)
    assert CLOUD_SPEC.observation_shape == (60, 60, 3)
    assert CLOUD_SPEC.n_convs == 3
    assert CLOUD_SPEC.conv_output_shape == (16, 6, 6)  # 60 -> 29 -> 14 -> 6
    assert CLOUD_SPEC.flattened_size == 576
    assert CLOUD_SPEC.actor_layers == (512, 256, 60)
    assert CLOUD_SPEC.critic_layers == (512, 256, 128, 54, 1)
    assert get_network_spec("edge") is EDGE_SPEC
    assert get_network_spec("cloud") is CLOUD_SPEC
    with pytest.raises(ValueError, match="unknown node kind"):
        get_network_spec("end")  # type: ignore[arg-type]


def test_spec_rejects_inconsistent_flattened_size() -> None:
    with pytest.raises(ValueError, match="flattened"):
        dataclasses.replace(EDGE_SPEC, flattened_size=145)


@pytest.mark.parametrize("kind", KINDS)
def test_flattened_size_from_running_convs(kind: str) -> None:
    spec = NETWORK_SPECS[kind]
    obs = _observation(spec, (2,))
    for net in (make_actor_net(kind), make_critic_net(kind)):
        # The raw conv stack on channel-first input ...
        assert net.convs(obs.movedim(-1, -3)).shape == (2, spec.flattened_size)
        # ... and through the channel-last entry point.
        assert net.features(obs).shape == (2, spec.flattened_size)


# Hand arithmetic from the paper's table: conv = k*k*c_in*c_out + c_out,
# dense = n_in*n_out + n_out, LayerNorm = 2*n (weight and bias).
EDGE_CONVS = (3 * 3 * 3 * 32 + 32) + (3 * 3 * 32 * 16 + 16)  # 896 + 4624 = 5520
CLOUD_CONVS = (3 * 3 * 3 * 32 + 32) + (3 * 3 * 32 * 32 + 32) + (3 * 3 * 32 * 16 + 16)
# 896 + 9248 + 4624 = 14768
EXPECTED_PARAMETERS = {
    ("edge", "actor"): EDGE_CONVS
    + (144 * 96 + 96)  # 13920
    + (96 * 96 + 96)  # 9312
    + (96 * 15 + 15),  # 1455
    ("edge", "critic"): EDGE_CONVS
    + ((144 + 15) * 96 + 96)
    + 2 * 96  # 15360 + 192
    + (96 * 96 + 96)
    + 2 * 96  # 9312 + 192
    + (96 * 48 + 48)
    + 2 * 48  # 4656 + 96
    + (48 * 12 + 12)
    + 2 * 12  # 588 + 24
    + (12 * 1 + 1),  # 13
    ("cloud", "actor"): CLOUD_CONVS
    + (576 * 512 + 512)  # 295424
    + (512 * 256 + 256)  # 131328
    + (256 * 60 + 60),  # 15420
    ("cloud", "critic"): CLOUD_CONVS
    + ((576 + 60) * 512 + 512)
    + 2 * 512  # 326144 + 1024
    + (512 * 256 + 256)
    + 2 * 256  # 131328 + 512
    + (256 * 128 + 128)
    + 2 * 128  # 32896 + 256
    + (128 * 54 + 54)
    + 2 * 54  # 6966 + 108
    + (54 * 1 + 1),  # 55
}


def test_expected_parameter_totals() -> None:
    # The sums above, worked out once more so that a typo in them cannot go unnoticed.
    assert EXPECTED_PARAMETERS == {
        ("edge", "actor"): 30_207,
        ("edge", "critic"): 35_953,
        ("cloud", "actor"): 456_940,
        ("cloud", "critic"): 514_057,
    }


@pytest.mark.parametrize("kind", KINDS)
def test_parameter_counts(kind: str) -> None:
    assert count_parameters(make_actor_net(kind)) == EXPECTED_PARAMETERS[(kind, "actor")]
    assert count_parameters(make_critic_net(kind)) == EXPECTED_PARAMETERS[(kind, "critic")]


def test_count_parameters_trainable_only() -> None:
    net = make_actor_net("edge")
    total = count_parameters(net)
    for p in net.convs.parameters():
        p.requires_grad_(False)
    assert count_parameters(net, trainable_only=True) == total - EDGE_CONVS
    assert count_parameters(net) == total


@pytest.mark.parametrize("kind", KINDS)
def test_layer_structure(kind: str) -> None:
    spec = NETWORK_SPECS[kind]
    actor, critic = make_actor_net(kind), make_critic_net(kind)
    for net in (actor, critic):
        convs = [m for m in net.convs.modules() if isinstance(m, nn.Conv2d)]
        assert [c.out_channels for c in convs] == list(spec.conv_filters)
        assert all(c.kernel_size == (3, 3) and c.stride == (2, 2) for c in convs)
        assert all(c.padding == (0, 0) for c in convs)  # "valid"
        activations = [m for m in net.convs if isinstance(m, (nn.ReLU, nn.Tanh))]
        assert len(activations) == spec.n_convs
        assert all(isinstance(m, nn.ReLU) for m in activations)
    actor_linears = [m for m in actor.mlp.modules() if isinstance(m, nn.Linear)]
    assert [m.out_features for m in actor_linears] == list(spec.actor_layers)
    assert actor_linears[0].in_features == spec.flattened_size
    assert sum(isinstance(m, nn.Tanh) for m in actor.mlp) == len(spec.actor_hidden)
    critic_layers = list(critic.mlp)
    critic_linears = [m for m in critic_layers if isinstance(m, nn.Linear)]
    assert [m.out_features for m in critic_linears] == list(spec.critic_layers)
    assert critic_linears[0].in_features == spec.flattened_size + spec.action_dim
    # Linear -> LayerNorm -> ReLU for each hidden layer, a bare Linear at the end.
    hidden = len(spec.critic_hidden)
    for i in range(hidden):
        lin, norm, act = critic_layers[3 * i : 3 * i + 3]
        assert isinstance(lin, nn.Linear)
        assert isinstance(norm, nn.LayerNorm)
        assert norm.normalized_shape == (lin.out_features,)
        assert isinstance(act, nn.ReLU)
    assert len(critic_layers) == 3 * hidden + 1
    assert isinstance(critic_layers[-1], nn.Linear)


def test_actor_conv_activation_option() -> None:
    relu_acts = [m for m in make_actor_net("edge").convs if not isinstance(m, nn.Conv2d)]
    tanh_acts = [
        m
        for m in make_actor_net("edge", conv_activation="tanh").convs
        if not isinstance(m, nn.Conv2d)
    ]
    assert sum(isinstance(m, nn.ReLU) for m in relu_acts) == 2
    assert sum(isinstance(m, nn.Tanh) for m in tanh_acts) == 2
    with pytest.raises(ValueError, match="conv_activation"):
        make_actor_net("edge", conv_activation="elu")  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------
# Shapes, bounds and masking
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("batch", LEADING_DIMS)
def test_shapes(kind: str, batch: tuple[int, ...], variant: str) -> None:
    spec = NETWORK_SPECS[kind]
    actor, critic = make_actor_net(kind, variant=variant), make_critic_net(kind, variant=variant)
    obs = _observation(spec, batch)
    mask = _mask(spec, batch, spec.action_dim)
    action = actor(obs, mask)
    assert action.shape == (*batch, spec.action_dim)
    assert critic(obs, action, mask).shape == (*batch, 1)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("kind", KINDS)
def test_leading_dims_are_independent(kind: str, variant: str) -> None:
    # Flattening the leading dims must not mix samples: (2, 3) equals six single calls.
    spec = NETWORK_SPECS[kind]
    actor, critic = make_actor_net(kind, variant=variant), make_critic_net(kind, variant=variant)
    obs = _observation(spec, (2, 3))
    mask = _mask(spec, (2, 3), spec.action_dim)
    action = actor(obs, mask)
    value = critic(obs, action, mask)
    for i in range(2):
        for j in range(3):
            torch.testing.assert_close(action[i, j], actor(obs[i, j], mask[i, j]))
            torch.testing.assert_close(value[i, j], critic(obs[i, j], action[i, j], mask[i, j]))


def test_actor_within_bounds_even_when_saturated() -> None:
    spec = EDGE_SPEC
    actor = make_actor_net("edge")
    with torch.no_grad():
        actor.output_layer.weight.mul_(1e4)  # drive tanh into saturation
    obs = _observation(spec, (16,)) * 10.0
    action = actor(obs, _mask(spec, (16,), spec.action_dim))
    assert action.abs().max() <= ACTION_SCALE_MPS2
    assert action.abs().max() > 0.9 * ACTION_SCALE_MPS2


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("kind", KINDS)
def test_actor_last_layer_init(kind: str, variant: str) -> None:
    layer = make_actor_net(kind, variant=variant).output_layer
    assert layer.weight.abs().max() <= ACTOR_FINAL_INIT_BOUND
    assert layer.bias.abs().max() <= ACTOR_FINAL_INIT_BOUND


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("mask_dtype", [torch.float32, torch.bool])
def test_actor_zero_in_padded_columns(kind: str, mask_dtype: torch.dtype, variant: str) -> None:
    spec = NETWORK_SPECS[kind]
    n_real = spec.action_dim // 3
    actor = make_actor_net(kind, variant=variant)
    mask = _mask(spec, (2, 4), n_real).to(mask_dtype)
    action = actor(_observation(spec, (2, 4)), mask)
    assert torch.equal(action[..., n_real:], torch.zeros_like(action[..., n_real:]))
    assert (action[..., :n_real] != 0).all()


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("kind", KINDS)
def test_padded_columns_give_no_actor_gradient(kind: str, variant: str) -> None:
    spec = NETWORK_SPECS[kind]
    n_real = 5
    actor = make_actor_net(kind, variant=variant)
    action = actor(_observation(spec, (3,)), _mask(spec, (3,), n_real))
    action[..., n_real:].sum().backward()
    for p in actor.parameters():
        assert p.grad is not None
        assert torch.count_nonzero(p.grad) == 0


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("kind", KINDS)
def test_critic_ignores_padded_actions(kind: str, variant: str) -> None:
    spec = NETWORK_SPECS[kind]
    n_real = 7
    critic = make_critic_net(kind, variant=variant)
    obs = _observation(spec, (2, 3))
    mask = _mask(spec, (2, 3), n_real).bool()
    gen = torch.Generator().manual_seed(1)
    action = 6 * torch.rand(2, 3, spec.action_dim, generator=gen) - 3
    changed = action.clone()
    changed[..., n_real:] = 6 * torch.rand(2, 3, spec.action_dim - n_real, generator=gen) - 3
    assert torch.equal(critic(obs, action, mask), critic(obs, changed, mask))
    # A change in a real column does change the value.
    changed_real = action.clone()
    changed_real[..., 0] += 1.0
    assert not torch.equal(critic(obs, action, mask), critic(obs, changed_real, mask))
    # No gradient flows to padded actions.
    action.requires_grad_(True)
    critic(obs, action, mask).sum().backward()
    assert torch.count_nonzero(action.grad[..., n_real:]) == 0
    assert torch.count_nonzero(action.grad[..., :n_real]) > 0


def test_shape_errors() -> None:
    actor, critic = make_actor_net("edge"), make_critic_net("edge")
    obs = _observation(EDGE_SPEC, (2,))
    mask = _mask(EDGE_SPEC, (2,), 15)
    with pytest.raises(ValueError, match="observation"):
        actor(_observation(CLOUD_SPEC, (2,)), mask)
    with pytest.raises(ValueError, match="mask"):
        actor(obs, mask[..., :14])
    with pytest.raises(ValueError, match="action"):
        critic(obs, torch.zeros(2, 60), mask)


# --------------------------------------------------------------------------------------------
# TensorDict wrappers
# --------------------------------------------------------------------------------------------


def _group_td(spec: NetworkSpec, batch: int, n_agents: int, n_real: int) -> TensorDict:
    """A group sub-TensorDict of shape ``(batch, n_agents)``."""
    return TensorDict(
        {
            "observation": _observation(spec, (batch, n_agents)),
            "mask": _mask(spec, (batch, n_agents), n_real),
        },
        batch_size=(batch, n_agents),
    )


@pytest.mark.parametrize(("kind", "n_agents"), [("edge", 9), ("cloud", 1)])
def test_tensordict_wrappers(kind: str, n_agents: int) -> None:
    spec = NETWORK_SPECS[kind]
    batch, n_real = 5, 4
    actor, critic = make_actor(kind, kind), make_critic(kind, kind)
    assert actor.in_keys == [(kind, "observation"), (kind, "mask")]
    assert actor.out_keys == [(kind, "action")]
    assert critic.in_keys == [(kind, "observation"), (kind, "action"), (kind, "mask")]
    assert critic.out_keys == [(kind, "state_action_value")]
    td = TensorDict({kind: _group_td(spec, batch, n_agents, n_real)}, batch_size=(batch,))
    td = critic(actor(td))
    action = td[kind, "action"]
    assert action.shape == (batch, n_agents, spec.action_dim)
    assert torch.equal(action[..., n_real:], torch.zeros_like(action[..., n_real:]))
    assert td[kind, "state_action_value"].shape == (batch, n_agents, 1)


@pytest.mark.filterwarnings("ignore:No target network updater")
def test_wrappers_work_in_ddpg_loss() -> None:

    batch, n_agents, group = 4, 9, "edge"
    actor, critic = make_actor("edge", group), make_critic("edge", group)
    td = TensorDict(
        {
            group: _group_td(EDGE_SPEC, batch, n_agents, 6),
            "next": TensorDict(
                {group: _group_td(EDGE_SPEC, batch, n_agents, 6)}, batch_size=(batch,)
            ),
        },
        batch_size=(batch,),
    )
    td[group, "action"] = torch.zeros(batch, n_agents, EDGE_SPEC.action_dim)
    td["next", group, "reward"] = torch.ones(batch, n_agents, 1)
    td["next", group, "done"] = torch.zeros(batch, n_agents, 1, dtype=torch.bool)
    td["next", group, "terminated"] = torch.zeros(batch, n_agents, 1, dtype=torch.bool)
    from mivecc_agents.training import make_loss

    loss = make_loss(actor, critic, group, gamma=0.8)
    out = loss(td)
    (out["loss_actor"] + out["loss_value"]).backward()
    assert torch.isfinite(out["loss_actor"]) and torch.isfinite(out["loss_value"])


# --------------------------------------------------------------------------------------------
# Seeding
# --------------------------------------------------------------------------------------------


def _same_weights(a: nn.Module, b: nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("kind", KINDS)
def test_generator_seeding(kind: str, variant: str) -> None:
    def gen(seed: int) -> torch.Generator:
        return torch.Generator().manual_seed(seed)

    global_state = torch.get_rng_state()
    actor_a = make_actor_net(kind, generator=gen(7), variant=variant)
    actor_b = make_actor_net(kind, generator=gen(7), variant=variant)
    critic_a = make_critic_net(kind, generator=gen(7), variant=variant)
    critic_b = make_critic_net(kind, generator=gen(7), variant=variant)
    # A generator leaves the global random state untouched.
    assert torch.equal(torch.get_rng_state(), global_state)
    assert _same_weights(actor_a, actor_b)
    assert _same_weights(critic_a, critic_b)
    assert not _same_weights(actor_a, make_actor_net(kind, generator=gen(8), variant=variant))
    assert not _same_weights(critic_a, make_critic_net(kind, generator=gen(8), variant=variant))
    # The DDPG output init is kept under a generator.
    assert actor_a.output_layer.weight.abs().max() <= ACTOR_FINAL_INIT_BOUND
    # The wrappers forward the generator.
    wrapped_actor = make_actor(kind, kind, generator=gen(7), variant=variant)
    wrapped_critic = make_critic(kind, kind, generator=gen(7), variant=variant)
    assert _same_weights(wrapped_actor.module, actor_a)
    assert _same_weights(wrapped_critic.module, critic_a)


def test_generator_init_matches_default_distribution() -> None:
    # Re-drawn weights keep PyTorch's default bounds: |w| <= 1/sqrt(fan_in) for Linear/Conv.
    net = make_critic_net("edge", generator=torch.Generator().manual_seed(0))
    for m in net.modules():
        if isinstance(m, (nn.Linear, nn.Conv2d)):
            fan_in = m.weight[0].numel()
            bound = 1.0 / fan_in**0.5
            assert m.weight.abs().max() <= bound
            assert m.bias.abs().max() <= bound
        if isinstance(m, nn.LayerNorm):
            assert torch.equal(m.weight, torch.ones_like(m.weight))
            assert torch.equal(m.bias, torch.zeros_like(m.bias))
