"""Trained policies for evaluation: numpy in, numpy out, deterministic (no noise).

``load_policy(path)`` returns ``fn(obs (n_agents, K, K, 3), mask (n_agents, K)) -> actions
(n_agents, K)`` [m/s^2], the signature ``evaluate_scheme(..., policies={"edge": fn, "cloud": fn})``
expects. :func:`pretrained_path` finds the checkpoints shipped in ``mivecc_agents/pretrained/``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from mivecc_agents.checkpoints import CheckpointError, load_checkpoint
from mivecc_agents.networks import ACTION_SCALE_MPS2, make_actor_net

__all__ = ["PRETRAINED_DIR", "Policy", "load_policy", "pretrained_path", "pretrained_policies"]

PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"
"""Package data folder of the shipped checkpoints (``edge.pt``, ``cloud.pt``)."""

Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]


def load_policy(path: str | Path, expected_kind: str | None = None) -> Policy:
    """Load a checkpoint's actor as a deterministic numpy policy.

    Args:
        path: Checkpoint file written by training.
        expected_kind: ``"edge"``/``"cloud"`` to check the kind (``None``: any).

    Returns:
        ``fn(obs, mask) -> actions``; ``obs`` is ``(n, K, K, 3)`` (or ``(K, K, 3)``), ``mask``
        ``(n, K)`` (or ``(K,)``); actions are float32 in [-3, 3], 0 in padded columns. The
        function carries ``.kind``, ``.grid_size`` and ``.checkpoint`` attributes.

    Raises:
        CheckpointError: If the file is not a usable checkpoint, or the state dict does not fit.
    """
    ckpt = load_checkpoint(path, expected_kind=expected_kind)
    kind = ckpt["kind"]
    net = make_actor_net(kind)
    try:
        net.load_state_dict(ckpt["actor"])
    except (RuntimeError, KeyError, TypeError) as exc:
        raise CheckpointError(
            f"{path}: actor weights do not fit the {kind} network: {exc}"
        ) from exc
    net.eval()
    for prm in net.parameters():
        prm.requires_grad_(False)
    k = net.spec.grid_size

    def policy(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        o = torch.as_tensor(np.asarray(obs, dtype=np.float32))
        m = torch.as_tensor(np.asarray(mask, dtype=np.float32))
        if o.shape[-3:] != (k, k, 3) or m.shape[-1] != k:
            raise ValueError(
                f"{kind} policy expects obs (..., {k}, {k}, 3) and mask (..., {k}), "
                f"got {tuple(o.shape)} and {tuple(m.shape)}"
            )
        with torch.no_grad():
            a = net(o, m).clamp(-ACTION_SCALE_MPS2, ACTION_SCALE_MPS2)
        return a.numpy().astype(np.float32, copy=False)

    policy.kind = kind  # type: ignore[attr-defined]
    policy.grid_size = k  # type: ignore[attr-defined]
    policy.checkpoint = str(path)  # type: ignore[attr-defined]
    return policy


def pretrained_path(kind: str) -> Path | None:
    """Path of the shipped pretrained checkpoint of a kind, or ``None`` if not shipped."""
    path = PRETRAINED_DIR / f"{kind}.pt"
    return path if path.is_file() else None


def pretrained_policies() -> dict[str, Policy]:
    """The shipped policies as ``{"edge": fn, "cloud": fn}`` (only the kinds available)."""
    out: dict[str, Policy] = {}
    for kind in ("edge", "cloud"):
        path = pretrained_path(kind)
        if path is not None:
            out[kind] = load_policy(path, expected_kind=kind)
    return out
