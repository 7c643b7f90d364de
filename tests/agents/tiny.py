"""A tiny training preset for fast tests (real training, few frames)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mivecc_agents.presets import get_preset

TINY = get_preset("stable").replace(
    name="tiny",
    frames_per_batch=50,
    warmup_frames=48,
    batch_size=48,
    updates_per_frame=0.1,
    episode_steps=120,
    buffer_size=500,
    envs_per_density=2,
)


def train_tiny_edge(out_dir: Path, preset: Any = TINY, **kwargs: Any) -> Path:
    """A 200-frame stage-I run on 1x1 at 1500 veh/lane/h (2 envs); returns the checkpoint."""
    from mivecc_agents.training import train

    return train("edge", preset, frames=200, rows=1, cols=1, densities=1500, seed=0,
                 out_dir=out_dir, progress=False, **kwargs)


def retrain_is_identical(train: Any, settings: Any, first: Any, network: str) -> list:
    """Train again with ``settings``: torch's global random state must be left as it was and
    the policy's ``network`` module must equal ``first``'s bit for bit; returns the new log."""
    import torch

    state = torch.random.get_rng_state()
    again, log = train(settings)
    assert torch.equal(torch.random.get_rng_state(), state)
    for a, b in zip(getattr(first, network).state_dict().values(),
                    getattr(again, network).state_dict().values(), strict=True):
        assert torch.equal(a, b)
    return log


def keep_best_and_last(train: Any, settings_cls: Any, base: dict[str, Any],
                       network: str) -> tuple[Any, list, Any, list, list]:
    """Train ``base`` (every episode validated) keeping the best network, with every validated
    network copied through ``on_validated``, and again keeping the last: the copies come one per
    episode, and the last one's ``network`` module is the one ``keep_network="last"`` returns.
    Returns ``(best, log, last, last_log, copies)``, ``copies`` as ``(row, policy)`` pairs."""
    import torch

    copies: list = []
    best, log = train(settings_cls(**base),  # keep_network="best", the default
                      on_validated=lambda row, policy: copies.append((row, policy)))
    last, last_log = train(settings_cls(**{**base, "keep_network": "last"}))
    assert [row["episode"] for row, _ in copies] == list(range(1, base["episodes"] + 1))
    for a, b in zip(getattr(copies[-1][1], network).parameters(),
                    getattr(last, network).parameters(), strict=True):
        assert torch.equal(a, b)
    return best, log, last, last_log, copies
