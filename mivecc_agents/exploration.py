"""Exploration noise of the training presets (``TrainPreset.exploration``).

* ``"per_column"``: TorchRL's ``AdditiveGaussianModule``, one independent N(0, sigma^2) number
  per action column (every decision vehicle of every agent).
* ``"scalar"``: :class:`ScalarGaussianModule`, the released trainer's edge exploration: one
  N(0, sigma^2) number per environment and step, added to every action of that environment.
* ``"none"``: no module (the released trainer's cloud stage explores only through its initial
  weights).

With ``uniform_prob`` > 0 (``TrainPreset.explore_uniform_prob``) each action column is then, with
that probability, replaced by a draw from the uniform distribution over the action bounds
(:class:`UniformColumnsModule`): the critic keeps seeing every action, also where the actor has
settled at a bound.

Sigma is annealed linearly from ``sigma_init`` to ``sigma_end`` over ``annealing_num_steps``
frames in both noisy forms (the released preset keeps it at 0.1). Noise is drawn from torch's
global generator, which training seeds inside ``torch.random.fork_rng``.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.modules import AdditiveGaussianModule

from mivecc_agents.presets import check_uniform_exploration

__all__ = ["EXPLORATIONS", "ScalarGaussianModule", "UniformColumnsModule", "make_exploration"]

EXPLORATIONS: tuple[str, ...] = ("per_column", "scalar", "none")


class ScalarGaussianModule(AdditiveGaussianModule):
    """One Gaussian number per environment (leading batch element) and step, shared by all
    of its agents' action columns; then projected into the action spec's bounds."""

    def _add_noise(self, action: torch.Tensor) -> torch.Tensor:
        shape = (action.shape[0], *([1] * (action.ndim - 1))) if action.ndim else ()
        noise = torch.randn(shape, dtype=action.dtype, device=action.device) * self.sigma
        return self.spec[self.action_key].project(action + noise)


class UniformColumnsModule(TensorDictModuleBase):
    """Replace each action column, with probability ``prob``, by a uniform draw over the action
    spec's bounds (after the Gaussian module ``inner`` has added its noise).

    Args:
        inner: The Gaussian exploration module (its ``step`` anneals sigma as usual).
        prob: Probability of replacing a column, in (0, 1].
    """

    def __init__(self, inner: AdditiveGaussianModule, prob: float) -> None:
        super().__init__()
        self.inner = inner
        self.prob = float(prob)
        self.in_keys = inner.in_keys
        self.out_keys = inner.out_keys

    @property
    def sigma(self) -> torch.Tensor:
        """The inner module's current sigma [m/s^2]."""
        return self.inner.sigma

    def step(self, frames: int = 1) -> None:
        """Anneal the inner module's sigma by ``frames`` frames."""
        self.inner.step(frames)

    def forward(self, tensordict: Any) -> Any:
        tensordict = self.inner(tensordict)
        if exploration_type() not in (ExplorationType.RANDOM, None):
            return tensordict  # deterministic evaluation: no noise at all
        key = self.inner.action_key
        action = tensordict.get(key)
        space = self.inner.spec[key].space
        uniform = space.low + (space.high - space.low) * torch.rand_like(action)
        replace = torch.rand_like(action) < self.prob
        tensordict.set(key, torch.where(replace, uniform, action))
        return tensordict


def make_exploration(
    kind: str,
    spec: Any,
    sigma_init: float,
    sigma_end: float,
    annealing_num_steps: int,
    action_key: Any,
    uniform_prob: float = 0.0,
) -> AdditiveGaussianModule | UniformColumnsModule | None:
    """The exploration module of a preset, or ``None`` for ``"none"``.

    Raises:
        ValueError: an unknown ``kind``, or ``uniform_prob`` > 0 with ``"none"``.
    """
    check_uniform_exploration(kind, uniform_prob)
    if kind == "none":
        return None
    cls = {"per_column": AdditiveGaussianModule, "scalar": ScalarGaussianModule}.get(kind)
    if cls is None:
        raise ValueError(f"exploration: must be one of {EXPLORATIONS}, got {kind!r}")
    module = cls(
        spec=spec,
        sigma_init=sigma_init,
        sigma_end=sigma_end,
        annealing_num_steps=max(1, int(annealing_num_steps)),
        action_key=action_key,
    )
    return UniformColumnsModule(module, uniform_prob) if uniform_prob > 0 else module
