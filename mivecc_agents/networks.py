"""Actor and critic networks of the MiVeCC coordinators (paper Table "HyperParameter").

Every coordinator (an edge node or the cloud node) reads a state graph (SG) of shape
``(K, K, 3)``, channel-last, and outputs one acceleration [m/s^2] per column of the graph, i.e.
per selected decision vehicle. The layer sizes below are the paper's table:

====================  ===========================  ===========================
                      cloud (K = 60)               edge (K = 15)
====================  ===========================  ===========================
state graph input     (60, 60, 3)                  (15, 15, 3)
action set input      60                           15
convolutions          32, 32, 16 (3x3, s2, valid)  32, 16 (3x3, s2, valid)
flattened elements    576 = 16 * 6 * 6             144 = 16 * 3 * 3
actor dense           512, 256, 60                 96, 96, 15
critic dense          512, 256, 128, 54, 1         96, 96, 48, 12, 1
====================  ===========================  ===========================

Readings of the paper used here (the paper leaves them open):

* Actor and critic each own their convolution stack (nothing is shared), as the paper's figure
  draws two separate networks.
* The convolutions use ReLU in both networks (the paper names no activation for them). The
  actor's ones can be switched to tanh with ``conv_activation="tanh"``, the other literal
  reading of "for actor tanh is adopted as activation function".
* Actor: tanh after every dense layer; the last layer's tanh output is multiplied by
  :data:`ACTION_SCALE_MPS2` = 3, so actions lie in [-3, 3] m/s^2.
* Critic: the action set is concatenated *after* the flattened convolution features
  (``[features, action]``), then dense layers with ``Linear -> LayerNorm -> ReLU`` for every
  hidden layer (the ordering of the DDPG reference implementations, and of
  :class:`torchrl.modules.MLP`); the final 1-unit layer is linear, without LayerNorm. There is
  no normalisation in the convolution stack.
* The flatten order is PyTorch's channel-first ``(C, H, W)``, not the TensorFlow ``(H, W, C)``
  of a channel-last implementation: a fixed permutation of the 576/144 inputs, irrelevant for
  networks trained from scratch.
* Initialisation: PyTorch's defaults (Kaiming-uniform weights, fan-in uniform biases; LayerNorm
  ones/zeros), except the actor's last dense layer, whose weight and bias are drawn from
  uniform(-3e-3, 3e-3) as in the DDPG paper (Lillicrap et al., 2016), so that initial actions
  are near 0 m/s^2 and tanh starts unsaturated.

Masking: each observation comes with a mask ``(..., K)`` of real columns (1 = decision
vehicle, 0 = zero padding). The actor returns exactly 0 for padded columns and the critic
multiplies the action by the mask before using it, so padded columns neither act nor receive
gradient.

The building blocks are TorchRL's :class:`~torchrl.modules.ConvNet` (``paddings=0`` is "valid",
ReLU after every convolution, :class:`~torchrl.modules.models.utils.SquashDims` flattens) and
:class:`~torchrl.modules.MLP` (``norm_class=nn.LayerNorm`` places the norm between each hidden
``Linear`` and its activation and not after the output layer): both reproduce the table's
layer sizes, strides, padding and LayerNorm placement exactly, so no custom layers are needed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import torch
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import nn
from torchrl.modules import MLP, ConvNet, ValueOperator

__all__ = [
    "ACTION_SCALE_MPS2",
    "ACTOR_FINAL_INIT_BOUND",
    "CLOUD_SPEC",
    "EDGE_SPEC",
    "NETWORK_SPECS",
    "NETWORK_VARIANTS",
    "ConvActivation",
    "CriticEnsembleNet",
    "MiVeCCActorNet",
    "MiVeCCCriticNet",
    "NetworkSpec",
    "NetworkVariant",
    "NodeKind",
    "PerPickActorNet",
    "PerPickCriticNet",
    "count_parameters",
    "critic_members_in",
    "get_network_spec",
    "make_actor",
    "make_actor_net",
    "make_critic",
    "make_critic_net",
    "reset_parameters",
]

NodeKind = Literal["edge", "cloud"]
"""Which coordinator a network belongs to."""

ConvActivation = Literal["relu", "tanh"]
"""Activation after each convolution of the actor (the critic's are always ReLU)."""
NetworkVariant = Literal["paper", "released", "per_pick"]
"""Network family: the paper's table, the authors' released code, or one network shared by
every column (:class:`PerPickActorNet`, :class:`PerPickCriticNet`)."""

ACTION_SCALE_MPS2: float = 3.0
"""Actor output scale [m/s^2]: ``action = 3 * tanh(.)`` lies in [-3, 3] m/s^2."""

ACTOR_FINAL_INIT_BOUND: float = 3e-3
"""Half-width of the uniform init of the actor's last layer (weight and bias), as in DDPG."""

_ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "tanh": nn.Tanh}


def _conv_out_size(size: int, kernel: int, stride: int) -> int:
    """Side length after one "valid" (unpadded) convolution.

    Args:
        size: Input side length [cells].
        kernel: Kernel side length [cells].
        stride: Stride [cells].

    Returns:
        Output side length [cells], ``(size - kernel) // stride + 1``.
    """
    return (size - kernel) // stride + 1


@dataclass(frozen=True)
class NetworkSpec:
    """Layer sizes of one node kind's actor and critic (the paper's table).

    Attributes:
        kind: Node kind, ``"edge"`` or ``"cloud"``.
        grid_size: K, the side of the K x K x 3 state graph and the number of action columns
            (decision vehicles) [-].
        in_channels: Channels of the state graph [-] (3 in the paper).
        conv_filters: Filters of each convolution, in order [-].
        kernel_size: Side of every convolution kernel [cells].
        stride: Stride of every convolution [cells].
        flattened_size: Number of features after the last convolution, as printed in the paper
            [-]; checked against the geometry in ``__post_init__``.
        actor_layers: Output sizes of the actor's dense layers; the last equals ``grid_size``.
        critic_layers: Output sizes of the critic's dense layers; the last is 1.
        variant: ``"paper"`` (the table above), ``"released"`` (the authors' released
            networks: a LayerNorm over the input graph, over the flattened convolution
            features and after every hidden dense layer of actor and critic, tanh after the
            actor's convolutions, every dense weight and bias drawn in +-3e-3, and the
            released critic widths 96-96-48-24-1 / 512-256-64-1; :func:`get_network_spec`)
            or ``"per_pick"`` (:class:`PerPickActorNet`: no convolutions, one MLP shared by
            every column; ``actor_layers`` then ends with K for the K columns of one output
            each, and the convolution fields are unused).
    """

    kind: NodeKind
    grid_size: int
    in_channels: int
    conv_filters: tuple[int, ...]
    kernel_size: int
    stride: int
    flattened_size: int
    actor_layers: tuple[int, ...]
    critic_layers: tuple[int, ...]
    variant: NetworkVariant = "paper"

    def __post_init__(self) -> None:
        """Check that the table's numbers are consistent with each other.

        Raises:
            ValueError: If the flattened size, the actor output or the critic output does not
                match the rest of the spec.
        """
        if math.prod(self.conv_output_shape) != self.flattened_size:
            raise ValueError(
                f"{self.kind}: convolutions give {self.conv_output_shape}, not "
                f"{self.flattened_size} flattened elements"
            )
        if self.actor_layers[-1] != self.grid_size:
            raise ValueError(f"{self.kind}: actor must output {self.grid_size} actions")
        if self.critic_layers[-1] != 1:
            raise ValueError(f"{self.kind}: critic must output one value")

    @property
    def n_convs(self) -> int:
        """Number of convolution layers [-]."""
        return len(self.conv_filters)

    @property
    def action_dim(self) -> int:
        """Size of the action set, one acceleration per column [-]."""
        return self.grid_size

    @property
    def observation_shape(self) -> tuple[int, int, int]:
        """Channel-last state-graph shape ``(K, K, C)``."""
        return (self.grid_size, self.grid_size, self.in_channels)

    @property
    def conv_output_shape(self) -> tuple[int, int, int]:
        """Channel-first shape ``(C, H, W)`` after the last convolution."""
        side = self.grid_size
        for _ in self.conv_filters:
            side = _conv_out_size(side, self.kernel_size, self.stride)
        return (self.conv_filters[-1], side, side)

    @property
    def actor_hidden(self) -> tuple[int, ...]:
        """Hidden dense sizes of the actor (all but the output layer)."""
        return self.actor_layers[:-1]

    @property
    def critic_hidden(self) -> tuple[int, ...]:
        """Hidden dense sizes of the critic (all but the output layer)."""
        return self.critic_layers[:-1]

    @property
    def critic_input_size(self) -> int:
        """Input of the critic's first dense layer: flattened features plus actions [-]."""
        return self.flattened_size + self.action_dim


EDGE_SPEC = NetworkSpec(
    kind="edge",
    grid_size=15,
    in_channels=3,
    conv_filters=(32, 16),
    kernel_size=3,
    stride=2,
    flattened_size=144,
    actor_layers=(96, 96, 15),
    critic_layers=(96, 96, 48, 12, 1),
)
"""Edge node: 15 x 15 x 3 state graph, 15 decision vehicles."""

CLOUD_SPEC = NetworkSpec(
    kind="cloud",
    grid_size=60,
    in_channels=3,
    conv_filters=(32, 32, 16),
    kernel_size=3,
    stride=2,
    flattened_size=576,
    actor_layers=(512, 256, 60),
    critic_layers=(512, 256, 128, 54, 1),
)
"""Cloud node: 60 x 60 x 3 state graph, 60 decision vehicles."""

NETWORK_SPECS: dict[str, NetworkSpec] = {"edge": EDGE_SPEC, "cloud": CLOUD_SPEC}
"""The specs by node kind."""


#: Critic widths of the authors' released code (not the paper's table).
RELEASED_CRITIC_LAYERS: dict[str, tuple[int, ...]] = {
    "edge": (96, 96, 48, 24, 1),
    "cloud": (512, 256, 64, 1),
}
#: Hidden widths of the per-pick networks (one small MLP applied to every column).
PER_PICK_ACTOR_HIDDEN: tuple[int, ...] = (256, 128)
PER_PICK_CRITIC_HIDDEN: tuple[int, ...] = (256, 128, 64)
NETWORK_VARIANTS: tuple[str, ...] = ("paper", "released", "per_pick")


def get_network_spec(kind: NodeKind, variant: NetworkVariant = "paper") -> NetworkSpec:
    """Return the layer sizes of a node kind.

    Args:
        kind: ``"edge"`` or ``"cloud"``.
        variant: ``"paper"`` (the paper's table) or ``"released"`` (see :class:`NetworkSpec`).

    Returns:
        The kind's :class:`NetworkSpec`.

    Raises:
        ValueError: If ``kind`` or ``variant`` is not known.
    """
    try:
        spec = NETWORK_SPECS[kind]
    except KeyError:
        raise ValueError(
            f"unknown node kind {kind!r}; expected one of {sorted(NETWORK_SPECS)}"
        ) from None
    if variant == "paper":
        return spec
    if variant == "per_pick":  # the convolution fields stay (unused): K and C still apply
        return dataclasses.replace(
            spec, actor_layers=(*PER_PICK_ACTOR_HIDDEN, spec.grid_size),
            critic_layers=(*PER_PICK_CRITIC_HIDDEN, 1), variant="per_pick",
        )
    if variant != "released":
        raise ValueError(f"network variant: must be one of {NETWORK_VARIANTS}, got {variant!r}")
    return dataclasses.replace(
        spec, critic_layers=RELEASED_CRITIC_LAYERS[kind], variant="released"
    )


def _make_conv_stack(
    spec: NetworkSpec, activation: type[nn.Module], device: torch.device | str | None
) -> ConvNet:
    """Build the convolution stack ``(N, C, K, K) -> (N, flattened_size)``.

    Args:
        spec: Layer sizes.
        activation: Activation class applied after every convolution.
        device: Device of the parameters.

    Returns:
        A TorchRL ConvNet with "valid" padding and a flattening aggregator.
    """
    return ConvNet(
        in_features=spec.in_channels,
        num_cells=list(spec.conv_filters),
        kernel_sizes=spec.kernel_size,
        strides=spec.stride,
        paddings=0,
        activation_class=activation,
        device=device,
    )


def _check_observation(observation: torch.Tensor, spec: NetworkSpec) -> None:
    """Raise ValueError if an observation is not ``(..., K, K, C)``."""
    if tuple(observation.shape[-3:]) != spec.observation_shape:
        raise ValueError(
            f"{spec.kind} observation must end with {spec.observation_shape}, "
            f"got {tuple(observation.shape)}"
        )


def _check_columns(name: str, tensor: torch.Tensor, spec: NetworkSpec) -> None:
    """Raise ValueError if a mask or action does not end with K columns."""
    if tensor.ndim == 0 or tensor.shape[-1] != spec.action_dim:
        raise ValueError(
            f"{spec.kind} {name} must end with {spec.action_dim} columns, got {tuple(tensor.shape)}"
        )


def _conv_features(convs: nn.Module, observation: torch.Tensor, spec: NetworkSpec) -> torch.Tensor:
    """Run a convolution stack on channel-last input with any number of leading dims.

    Args:
        convs: Convolution stack taking ``(N, C, K, K)``.
        observation: State graphs ``(..., K, K, C)``.
        spec: Layer sizes.

    Returns:
        Features ``(..., flattened_size)``.
    """
    _check_observation(observation, spec)
    batch_shape = observation.shape[:-3]
    x = observation.reshape(-1, *spec.observation_shape).movedim(-1, -3)
    return convs(x).reshape(*batch_shape, spec.flattened_size)


class _ConvNode(nn.Module):
    """Shared part of the actor and the critic: a convolution stack over the state graph
    (released variant: with a LayerNorm over the input graph and one over the features)."""

    spec: NetworkSpec
    convs: nn.Module

    def _make_norms(self, device: torch.device | str | None) -> None:
        released = self.spec.variant == "released"
        self.input_norm = (nn.LayerNorm(list(self.spec.observation_shape), device=device)
                           if released else nn.Identity())
        self.feature_norm = (nn.LayerNorm(self.spec.flattened_size, device=device)
                             if released else nn.Identity())

    def features(self, observation: torch.Tensor) -> torch.Tensor:
        """Flattened convolution features.

        Args:
            observation: State graphs ``(..., K, K, 3)``, channel-last.

        Returns:
            Features ``(..., flattened_size)``.
        """
        _check_observation(observation, self.spec)
        x = self.input_norm(observation)
        return self.feature_norm(_conv_features(self.convs, x, self.spec))


class _SquashedActor:
    """What every actor shares: ``action = 3 * tanh(preactivation) * mask`` and its output layer
    (a mixin: the subclass supplies ``spec``, ``mlp`` and :meth:`preactivation`)."""

    spec: NetworkSpec
    mlp: nn.Module

    def preactivation(self, observation: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    @property
    def output_layer(self) -> nn.Linear:
        """The last dense layer (initialised in +-3e-3)."""
        return _last_linear(self.mlp)

    def start_near(self, accel_mps2: float) -> None:
        """Set the output layer's bias to ``atanh(accel_mps2 / 3)``: with the small output
        weights of the DDPG initialisation, every column's action then starts near
        ``accel_mps2`` [m/s^2], in (-3, 3).

        Raises:
            ValueError: ``accel_mps2`` not a finite number strictly inside (-3, 3).
        """
        if not (math.isfinite(accel_mps2) and abs(accel_mps2) < ACTION_SCALE_MPS2):
            raise ValueError(f"accel_mps2: must be a number in (-3, 3) m/s^2, got {accel_mps2!r}")
        with torch.no_grad():
            self.output_layer.bias.fill_(math.atanh(accel_mps2 / ACTION_SCALE_MPS2))

    def forward(self, observation: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Compute the accelerations of the decision vehicles.

        Args:
            observation: State graphs ``(..., K, K, 3)``, channel-last.
            mask: Real columns ``(..., K)``, bool or float (1 = vehicle, 0 = padding).

        Returns:
            Accelerations ``(..., K)`` [m/s^2] in [-3, 3]; exactly 0 in padded columns.
        """
        _check_columns("mask", mask, self.spec)
        action = ACTION_SCALE_MPS2 * torch.tanh(self.preactivation(observation))
        return action * mask.to(action.dtype)


class MiVeCCActorNet(_SquashedActor, _ConvNode):
    """Deterministic actor: state graph -> one acceleration [m/s^2] per column.

    ``observation (..., K, K, 3) -> convs -> flatten -> dense (tanh) ... -> 3 * tanh -> * mask``.

    Args:
        spec: Layer sizes of the node kind.
        conv_activation: Activation after each convolution (``"relu"`` by default).
        device: Device of the parameters.
    """

    def __init__(
        self,
        spec: NetworkSpec,
        *,
        conv_activation: ConvActivation = "relu",
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        if conv_activation not in _ACTIVATIONS:
            raise ValueError(
                f"unknown conv_activation {conv_activation!r}; expected one of "
                f"{sorted(_ACTIVATIONS)}"
            )
        self.spec = spec
        released = spec.variant == "released"
        if released:
            conv_activation = "tanh"
        self.convs = _make_conv_stack(spec, _ACTIVATIONS[conv_activation], device)
        self._make_norms(device)
        self.mlp = MLP(
            in_features=spec.flattened_size,
            out_features=spec.action_dim,
            num_cells=list(spec.actor_hidden),
            activation_class=nn.Tanh,
            device=device,
            **(_hidden_norms(spec.actor_hidden) if released else {}),
        )
        _init_dense(self, generator=None)

    def preactivation(self, observation: torch.Tensor) -> torch.Tensor:
        """The last dense layer's output ``z`` (..., K), before ``action = 3 * tanh(z)``.

        Where ``|z|`` is large the action sits at a bound and its gradient ``3 (1 - tanh(z)^2)``
        vanishes: the actor stops learning there (the penalty of
        :func:`mivecc_agents.learner.preactivation_penalty` keeps ``|z|`` bounded).
        """
        return self.mlp(self.features(observation))


class MiVeCCCriticNet(_ConvNode):
    """Q-network: (state graph, action set) -> state-action value.

    ``observation -> convs -> flatten -> concat(features, action * mask) ->
    [Linear -> LayerNorm -> ReLU] * n_hidden -> Linear(1)``.

    Args:
        spec: Layer sizes of the node kind.
        device: Device of the parameters.
    """

    def __init__(self, spec: NetworkSpec, *, device: torch.device | str | None = None) -> None:
        super().__init__()
        self.spec = spec
        self.convs = _make_conv_stack(spec, nn.ReLU, device)
        self._make_norms(device)
        self.mlp = MLP(
            in_features=spec.critic_input_size,
            out_features=spec.critic_layers[-1],
            num_cells=list(spec.critic_hidden),
            activation_class=nn.ReLU,
            device=device,
            **_hidden_norms(spec.critic_hidden),
        )
        if spec.variant == "released":
            _init_dense(self, generator=None)

    def forward(
        self, observation: torch.Tensor, action: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """Evaluate an action set in a state.

        Args:
            observation: State graphs ``(..., K, K, 3)``, channel-last.
            action: Accelerations ``(..., K)`` [m/s^2]; padded columns are ignored.
            mask: Real columns ``(..., K)``, bool or float (1 = vehicle, 0 = padding).

        Returns:
            State-action values ``(..., 1)``.
        """
        _check_columns("action", action, self.spec)
        _check_columns("mask", mask, self.spec)
        features = self.features(observation)
        masked_action = action * mask.to(action.dtype)
        batch_shape = torch.broadcast_shapes(features.shape[:-1], masked_action.shape[:-1])
        features = features.expand(*batch_shape, self.spec.flattened_size)
        masked_action = masked_action.expand(*batch_shape, self.spec.action_dim)
        return self.mlp(torch.cat([features, masked_action], dim=-1))


class _PerPickNode(nn.Module):
    """Shared part of the per-pick actor and critic: one MLP applied to every column.

    ``column (K x C values) + extra_inputs -> [Linear -> LayerNorm -> activation] * hidden ->
    Linear(1)``; column j of a state graph is decision vehicle j (row 0 the vehicle itself,
    rows 1..K-1 its nearest reference vehicles).
    """

    def __init__(self, spec: NetworkSpec, hidden: Sequence[int], activation: type[nn.Module],
                 extra_inputs: int, device: torch.device | str | None) -> None:
        super().__init__()
        self.spec = spec
        k, _, c = spec.observation_shape
        self.mlp = MLP(in_features=k * c + extra_inputs, out_features=1, num_cells=list(hidden),
                       activation_class=activation, device=device, **_hidden_norms(hidden))

    def columns(self, observation: torch.Tensor) -> torch.Tensor:
        """Each column's view as one flat vector: ``(..., K, K, C) -> (..., K, K * C)``, rows in
        order, channels innermost."""
        _check_observation(observation, self.spec)
        k, _, c = self.spec.observation_shape
        return observation.transpose(-3, -2).reshape(*observation.shape[:-3], k, k * c)


class PerPickActorNet(_SquashedActor, _PerPickNode):
    """Actor sharing one MLP over the columns: column j's view -> vehicle j's acceleration.

    ``column (K * 3) -> [Linear -> LayerNorm -> tanh] * n_hidden -> Linear(1) -> 3 * tanh``,
    the same weights for every column, so the action of a vehicle depends on what its column
    shows (itself and its nearest vehicles), not on its rank among the picks. Permuting the
    columns permutes the actions.

    Args:
        spec: A ``"per_pick"`` spec (:func:`get_network_spec`).
        device: Device of the parameters.
    """

    def __init__(self, spec: NetworkSpec, *, device: torch.device | str | None = None) -> None:
        super().__init__(spec, spec.actor_hidden, nn.Tanh, 0, device)
        _init_dense(self, generator=None)

    def preactivation(self, observation: torch.Tensor) -> torch.Tensor:
        """The last dense layer's output ``z`` (..., K), before ``action = 3 * tanh(z)``."""
        return self.mlp(self.columns(observation)).squeeze(-1)


class PerPickCriticNet(_PerPickNode):
    """Critic: ``Q(s, a) = mean over the real columns j of q(column_j, a_j)``.

    ``q: [column (K * 3), a_j / 3] -> [Linear -> LayerNorm -> ReLU] * n_hidden -> Linear(1)``,
    one MLP for every column (a value decomposition over the picks, as VDN does over agents).
    Each transition then trains q on up to K (column, action) pairs, and the actor's gradient
    for vehicle j, ``dq(column_j, a_j) / da_j``, depends only on that vehicle's own view. A
    state with no real column has value 0.

    Args:
        spec: A ``"per_pick"`` spec (:func:`get_network_spec`).
        device: Device of the parameters.
    """

    def __init__(self, spec: NetworkSpec, *, device: torch.device | str | None = None) -> None:
        super().__init__(spec, spec.critic_hidden, nn.ReLU, 1, device)

    def forward(
        self, observation: torch.Tensor, action: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """State-action values ``(..., 1)``; padded columns' actions are ignored.

        Args:
            observation: State graphs ``(..., K, K, 3)``, channel-last.
            action: Accelerations ``(..., K)`` [m/s^2].
            mask: Real columns ``(..., K)``, bool or float (1 = vehicle, 0 = padding).
        """
        _check_columns("action", action, self.spec)
        _check_columns("mask", mask, self.spec)
        columns = self.columns(observation)
        real = mask.to(action.dtype)
        scaled = (action * real / ACTION_SCALE_MPS2).unsqueeze(-1)
        batch_shape = torch.broadcast_shapes(columns.shape[:-1], scaled.shape[:-1])
        inputs = torch.cat([columns.expand(*batch_shape, columns.shape[-1]),
                            scaled.expand(*batch_shape, 1)], dim=-1)
        q = self.mlp(inputs).squeeze(-1) * real
        return (q.sum(-1) / real.sum(-1).clamp(min=1.0)).unsqueeze(-1)


class CriticEnsembleNet(nn.Module):
    """Several critics side by side: ``(observation, action, mask) -> values (..., M)``.

    Member ``i`` writes column ``i``. Trained with DDPG's loss, each member fits its own TD(0)
    target, bootstrapped from its own target copy, and the actor climbs the mean of the
    members (:class:`mivecc_agents.learner.DDPGLearner`): an ensemble whose mean has less of
    one critic's fitting noise (the members start from their own initialisations).

    Args:
        members: The member critics (at least 2), all of one node kind.
    """

    def __init__(self, members: Sequence[nn.Module]) -> None:
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"members: an ensemble needs at least 2 critics, got {len(members)}")
        self.members = nn.ModuleList(members)
        self.spec = members[0].spec

    def forward(
        self, observation: torch.Tensor, action: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """Each member's state-action value, ``(..., M)`` (arguments as the members')."""
        return torch.cat([m(observation, action, mask) for m in self.members], dim=-1)


def critic_members_in(state_dict: dict[str, torch.Tensor]) -> int:
    """Number of critics a critic state dict holds (1 for a single critic's)."""
    indices = {key.split(".")[1] for key in state_dict if key.startswith("members.")}
    return len(indices) or 1


def _last_linear(module: nn.Module) -> nn.Linear:
    """Return the last ``nn.Linear`` of a module (in registration order)."""
    linears = [m for m in module.modules() if isinstance(m, nn.Linear)]
    if not linears:
        raise ValueError("module has no nn.Linear layer")
    return linears[-1]


def _hidden_norms(hidden: Sequence[int]) -> dict[str, object]:
    """MLP keywords placing a LayerNorm between each hidden Linear and its activation."""
    return {"norm_class": nn.LayerNorm,
            "norm_kwargs": [{"normalized_shape": n} for n in hidden]}


def _init_dense(net: nn.Module, generator: torch.Generator | None) -> None:
    """Dense-layer init of a network: the paper variant draws only the actor's last layer in
    +-3e-3 (DDPG); the released variant draws every dense weight and bias in +-3e-3."""
    if net.spec.variant != "released":
        _init_actor_output(net.mlp, generator)
        return
    with torch.no_grad():
        for layer in (m for m in net.mlp.modules() if isinstance(m, nn.Linear)):
            b = ACTOR_FINAL_INIT_BOUND
            nn.init.uniform_(layer.weight, -b, b, generator=generator)
            nn.init.uniform_(layer.bias, -b, b, generator=generator)


def _init_actor_output(mlp: nn.Module, generator: torch.Generator | None) -> None:
    """Draw the actor's last layer from uniform(-3e-3, 3e-3) (weight and bias), as in DDPG."""
    layer = _last_linear(mlp)
    with torch.no_grad():
        nn.init.uniform_(
            layer.weight, -ACTOR_FINAL_INIT_BOUND, ACTOR_FINAL_INIT_BOUND, generator=generator
        )
        if layer.bias is not None:
            nn.init.uniform_(
                layer.bias, -ACTOR_FINAL_INIT_BOUND, ACTOR_FINAL_INIT_BOUND, generator=generator
            )


def reset_parameters(module: nn.Module, generator: torch.Generator | None = None) -> None:
    """Re-draw every parameter with PyTorch's default initialisation, from ``generator``.

    Linear and convolution layers get ``kaiming_uniform_(a=sqrt(5))`` weights and
    uniform(+-1/sqrt(fan_in)) biases (what their ``reset_parameters`` does, but with an explicit
    generator); LayerNorm gets ones and zeros. The actor's DDPG output init is not applied here
    (the factories do it).

    Args:
        module: Module whose parameters are re-drawn in place.
        generator: Random source; ``None`` uses the global one.

    Raises:
        TypeError: If a submodule holds parameters of a type this function does not know.
    """
    with torch.no_grad():
        for sub in module.modules():
            own = list(sub.parameters(recurse=False))
            if not own:
                continue
            if isinstance(sub, (nn.Linear, nn.Conv2d)):
                nn.init.kaiming_uniform_(sub.weight, a=math.sqrt(5), generator=generator)
                if sub.bias is not None:
                    fan_in, _ = nn.init._calculate_fan_in_and_fan_out(sub.weight)
                    bound = 1.0 / math.sqrt(fan_in) if fan_in > 0 else 0.0
                    nn.init.uniform_(sub.bias, -bound, bound, generator=generator)
            elif isinstance(sub, nn.LayerNorm):
                sub.reset_parameters()
            else:
                raise TypeError(f"no generator-aware init for {type(sub).__name__}")


def make_actor_net(
    kind: NodeKind,
    *,
    generator: torch.Generator | None = None,
    conv_activation: ConvActivation = "relu",
    device: torch.device | str | None = None,
    variant: NetworkVariant = "paper",
) -> MiVeCCActorNet | PerPickActorNet:
    """Build the actor network of a node kind.

    Args:
        kind: ``"edge"`` or ``"cloud"``.
        generator: If given, every parameter is re-drawn from it (same seed, same weights) and
            the global random state is left untouched; otherwise PyTorch's global RNG is used.
        conv_activation: Activation after each convolution, ``"relu"`` (default) or ``"tanh"``
            (the released variant always uses tanh; the per-pick one has no convolutions).
        device: Device of the parameters.
        variant: ``"paper"``, ``"released"`` or ``"per_pick"`` (:class:`NetworkSpec`).

    Returns:
        ``forward(observation (..., K, K, 3), mask (..., K)) -> action (..., K)`` [m/s^2].
    """
    spec = get_network_spec(kind, variant)

    def build() -> MiVeCCActorNet | PerPickActorNet:
        if variant == "per_pick":
            return PerPickActorNet(spec, device=device)
        return MiVeCCActorNet(spec, conv_activation=conv_activation, device=device)

    if generator is None:
        return build()
    with torch.random.fork_rng(devices=[]):
        net = build()
    reset_parameters(net, generator)
    _init_dense(net, generator)
    return net


def make_critic_net(
    kind: NodeKind,
    *,
    generator: torch.Generator | None = None,
    device: torch.device | str | None = None,
    variant: NetworkVariant = "paper",
    members: int = 1,
) -> MiVeCCCriticNet | PerPickCriticNet | CriticEnsembleNet:
    """Build the critic network of a node kind.

    Args:
        kind: ``"edge"`` or ``"cloud"``.
        generator: If given, every parameter is re-drawn from it (same seed, same weights) and
            the global random state is left untouched; otherwise PyTorch's global RNG is used.
        device: Device of the parameters.
        variant: ``"paper"``, ``"released"`` or ``"per_pick"`` (:class:`NetworkSpec`).
        members: Critics side by side (:class:`CriticEnsembleNet`, each drawn after the one
            before); 1: a single critic.

    Returns:
        ``forward(observation (..., K, K, 3), action (..., K), mask (..., K)) -> value
        (..., members)``.
    """
    if members > 1:
        return CriticEnsembleNet([
            make_critic_net(kind, generator=generator, device=device, variant=variant)
            for _ in range(members)
        ])
    spec = get_network_spec(kind, variant)
    critic_class = PerPickCriticNet if variant == "per_pick" else MiVeCCCriticNet
    if generator is None:
        return critic_class(spec, device=device)
    with torch.random.fork_rng(devices=[]):
        net = critic_class(spec, device=device)
    reset_parameters(net, generator)
    if variant == "released":
        _init_dense(net, generator)
    return net


def _group_keys(group: str, names: Sequence[str]) -> list[NestedKey]:
    """Nested keys ``(group, name)`` for each name."""
    return [(group, name) for name in names]


def make_actor(
    kind: NodeKind,
    group: str,
    *,
    generator: torch.Generator | None = None,
    conv_activation: ConvActivation = "relu",
    device: torch.device | str | None = None,
    variant: NetworkVariant = "paper",
) -> TensorDictModule:
    """Wrap the actor network for a TorchRL multi-agent group.

    Args:
        kind: ``"edge"`` or ``"cloud"``.
        group: Agent group name in the TensorDict (e.g. ``"edge"``).
        generator: Optional random source for the weights (see :func:`make_actor_net`).
        conv_activation: Activation after each convolution (see :func:`make_actor_net`).
        device: Device of the parameters.

    Returns:
        A module reading ``(group, "observation")`` and ``(group, "mask")`` and writing
        ``(group, "action")`` [m/s^2].
    """
    net = make_actor_net(kind, generator=generator, conv_activation=conv_activation,
                         device=device, variant=variant)
    module = TensorDictModule(
        net,
        in_keys=_group_keys(group, ("observation", "mask")),
        out_keys=[(group, "action")],
    )
    # TensorDictModule forwards unknown attributes to its network, so ``module.spec`` would be
    # the network's NetworkSpec; TorchRL reads a policy's ``spec`` as the specs of its outputs
    # (a Collector given this module raised AttributeError). None: the collector finds the
    # outputs by calling the policy once. The network's spec stays ``module.module.spec``.
    module.spec = None
    return module


def make_critic(
    kind: NodeKind,
    group: str,
    *,
    generator: torch.Generator | None = None,
    device: torch.device | str | None = None,
    variant: NetworkVariant = "paper",
    members: int = 1,
) -> ValueOperator:
    """Wrap the critic network for a TorchRL multi-agent group.

    Args:
        kind: ``"edge"`` or ``"cloud"``.
        group: Agent group name in the TensorDict (e.g. ``"edge"``).
        generator: Optional random source for the weights (see :func:`make_critic_net`).
        device: Device of the parameters.
        variant: Network variant (see :func:`make_critic_net`).
        members: Critics side by side (see :func:`make_critic_net`).

    Returns:
        A ValueOperator reading ``(group, "observation")``, ``(group, "action")`` and
        ``(group, "mask")`` and writing ``(group, "state_action_value")`` with shape
        ``(..., members)``.
    """
    net = make_critic_net(kind, generator=generator, device=device, variant=variant,
                          members=members)
    return ValueOperator(
        net,
        in_keys=_group_keys(group, ("observation", "action", "mask")),
        out_keys=[(group, "state_action_value")],
    )


def count_parameters(module: nn.Module, *, trainable_only: bool = False) -> int:
    """Count the scalar parameters of a module.

    Args:
        module: Any module.
        trainable_only: Count only parameters with ``requires_grad``.

    Returns:
        Number of scalar parameters [-].
    """
    return sum(p.numel() for p in module.parameters() if p.requires_grad or not trainable_only)
