"""A tiny training preset for fast tests (real training, few frames)."""

from __future__ import annotations

from mivecc_agents.presets import get_preset

TINY = get_preset("stable").replace(
    name="tiny",
    frames_per_batch=50,
    warmup_frames=48,
    updates_per_frame=0.1,
    episode_steps=120,
    buffer_size=500,
)
