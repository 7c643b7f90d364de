"""The learned signal comparators' policy files: which one is shipped for a scheme and grid, and
reading any of them by the kind it holds (PA-DQN or Coder)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["load_signal_policy", "shipped_signal_policy_path"]


def shipped_signal_policy_path(scheme: str, rows: int, cols: int) -> Path:
    """The shipped policy of ``scheme`` (``"pa-dqn"`` or ``"coder"``) for a ``rows`` x ``cols``
    grid (PA-DQN: the 1x1 one for the single intersection, the 3x3 one otherwise; Coder: the
    3x3 one)."""
    if scheme == "coder":
        from mivecc_agents.coder import shipped_policy_path

        return shipped_policy_path()
    if scheme == "pa-dqn":
        from mivecc_agents.signal_dqn import shipped_policy_path

        return shipped_policy_path(rows, cols)
    raise ValueError(f"scheme: {scheme!r} has no learned signal policy")


def load_signal_policy(path: str | Path) -> Any:
    """The PA-DQN (:class:`~mivecc_agents.signal_dqn.SignalDQNPolicy`) or Coder
    (:class:`~mivecc_agents.coder.CoderPolicy`) policy in ``path``, by the kind it holds;
    :class:`~mivecc_agents.checkpoints.CheckpointError` for any other file."""
    from mivecc_agents.checkpoints import CheckpointError, read_checkpoint
    from mivecc_agents.coder import CODER_KIND, CoderPolicy
    from mivecc_agents.signal_dqn import SIGNAL_KIND, SignalDQNPolicy

    kind = read_checkpoint(path, ("kind",))["kind"]
    if kind == CODER_KIND:
        return CoderPolicy.load(path)
    if kind == SIGNAL_KIND:
        return SignalDQNPolicy.load(path)
    raise CheckpointError(f"{path}: holds the {kind!r} policy, but a signal policy "
                          f"({SIGNAL_KIND!r} or {CODER_KIND!r}) is needed")
