"""Exploration noise of the training presets (``TrainPreset.exploration``).

* ``"per_column"``: TorchRL's ``AdditiveGaussianModule``, one independent N(0, sigma^2) number
  per action column (every decision vehicle of every agent).
* ``"scalar"``: :class:`ScalarGaussianModule`, the released trainer's edge exploration: one
  N(0, sigma^2) number per environment and step, added to every action of that environment.
* ``"none"``: no module (the released trainer's cloud stage explores only through its initial
  weights).

Sigma is annealed linearly from ``sigma_init`` to ``sigma_end`` over ``annealing_num_steps``
frames in both noisy forms (the released preset keeps it at 0.1). Noise is drawn from torch's
global generator, which training seeds inside ``torch.random.fork_rng``.
"""

from __future__ import annotations

from typing import Any

import torch
from torchrl.modules import AdditiveGaussianModule

__all__ = ["EXPLORATIONS", "ScalarGaussianModule", "make_exploration"]

EXPLORATIONS: tuple[str, ...] = ("per_column", "scalar", "none")


class ScalarGaussianModule(AdditiveGaussianModule):
    """One Gaussian number per environment (leading batch element) and step, shared by all
    of its agents' action columns; then projected into the action spec's bounds."""

    def _add_noise(self, action: torch.Tensor) -> torch.Tensor:
        shape = (action.shape[0], *([1] * (action.ndim - 1))) if action.ndim else ()
        noise = torch.randn(shape, dtype=action.dtype, device=action.device) * self.sigma
        return self.spec[self.action_key].project(action + noise)


def make_exploration(
    kind: str,
    spec: Any,
    sigma_init: float,
    sigma_end: float,
    annealing_num_steps: int,
    action_key: Any,
) -> AdditiveGaussianModule | None:
    """The exploration module of a preset, or ``None`` for ``"none"``.

    Raises:
        ValueError: an unknown ``kind``.
    """
    if kind == "none":
        return None
    cls = {"per_column": AdditiveGaussianModule, "scalar": ScalarGaussianModule}.get(kind)
    if cls is None:
        raise ValueError(f"exploration: must be one of {EXPLORATIONS}, got {kind!r}")
    return cls(
        spec=spec,
        sigma_init=sigma_init,
        sigma_end=sigma_end,
        annealing_num_steps=max(1, int(annealing_num_steps)),
        action_key=action_key,
    )
