"""Training settings of PA-DQN (:mod:`mivecc_agents.signal_dqn`), without torch.

Kept apart from the trainer so that the ``mivecc`` command line can list them as options without
importing torch.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mivecc_env.config import ConfigError, MiVeCCConfig, from_overrides

__all__ = ["SignalDQNSettings", "check_choices", "check_densities", "check_numbers",
           "decision_steps", "plain_dict"]


def _opt(default: Any, help_text: str, choices: tuple[str, ...] = ()) -> Any:
    """A settings field with its help text (``field.metadata["help"]``) and, for a text
    field, its allowed values (``field.metadata["choices"]``)."""
    return field(default=default, metadata={"help": help_text, "choices": choices})


def check_choices(settings: Any) -> None:
    """Raise :class:`ConfigError` naming the first text field of ``settings`` whose value is
    not one of its ``choices``."""
    for f in dataclasses.fields(settings):
        allowed = f.metadata.get("choices")
        if allowed and getattr(settings, f.name) not in allowed:
            raise ConfigError(f"{f.name}: must be one of {', '.join(allowed)}, got "
                              f"{getattr(settings, f.name)!r}")


@dataclass(frozen=True)
class SignalDQNSettings:
    """Training settings of :func:`mivecc_agents.signal_dqn.train_signal_dqn` (each checked by
    :meth:`check`; ``field.metadata["help"]`` says what each one is)."""

    episodes: int = _opt(40, "training episodes; each runs `batch` environments for "
                         "`episode_steps` steps")
    batch: int = _opt(16, "environments stepped together")
    episode_steps: int = _opt(3000, "steps of 0.1 s per episode")
    densities: tuple[float, ...] = _opt((300.0, 600.0, 900.0, 1200.0, 1500.0, 1800.0, 2100.0,
                                         2100.0),
                                        "demands [veh/lane/h], cycled over the environments")
    rows: int = _opt(1, "intersection rows of the training grid")
    cols: int = _opt(1, "intersection columns of the training grid")
    decision_period_s: float = _opt(10.0, "time between two decisions of an agent [s]")
    reward_scale: float = _opt(0.2, "reward per vehicle that passed the centre")
    gamma: float = _opt(0.9, "discount per decision")
    lr: float = _opt(1e-3, "Adam learning rate")
    hidden: int = _opt(64, "units of each of the two hidden layers")
    buffer: int = _opt(100_000, "replay buffer size [transitions]")
    minibatch: int = _opt(128, "transitions per update")
    warmup: int = _opt(500, "transitions in the buffer before the first update")
    updates_per_decision: int = _opt(4, "gradient updates per decision of the batch")
    tau: float = _opt(0.01, "soft target update rate")
    eps_start: float = _opt(1.0, "exploration probability at the start")
    eps_end: float = _opt(0.05, "exploration probability after the decay")
    eps_decay_fraction: float = _opt(0.5, "share of the decisions over which the exploration "
                                     "decays linearly")
    seed: int = _opt(0, "seed of the network, the replay sampling, the exploration and the "
                     "training demand")
    keep_network: str = _opt(
        "best", "which network the training returns: `best`, of the networks after each "
        "episode once the exploration has decayed (and after the last episode), the one whose "
        "greedy run on validation environments (one per entry of `densities`, seeds 1000 on) "
        "moved the most vehicles out (Coder: per stage); `last`, the one it ended with (before "
        "session 46 the only one)", ("best", "last"))
    config: dict[str, Any] = field(default_factory=dict, metadata={
        "help": "further MiVeCCConfig fields of the training environments"})

    def check(self) -> SignalDQNSettings:
        """Return self, or raise :class:`ConfigError` naming the first bad field and its range."""
        ints = {"episodes": (1, 100_000), "batch": (1, 4096), "episode_steps": (1, 10**7),
                "rows": (1, 20), "cols": (1, 20), "hidden": (1, 4096),
                "buffer": (1, 10**8), "minibatch": (1, 65_536), "warmup": (1, 10**8),
                "updates_per_decision": (0, 1000), "seed": (0, 2**31)}
        floats = {"decision_period_s": (0.0, 600.0, True), "reward_scale": (0.0, 1e6, True),
                  "gamma": (0.0, 1.0, False), "lr": (0.0, 1.0, True), "tau": (0.0, 1.0, True),
                  "eps_start": (0.0, 1.0, False), "eps_end": (0.0, 1.0, False),
                  "eps_decay_fraction": (0.0, 1.0, True)}
        check_numbers(self, ints, floats)
        check_choices(self)
        check_densities(self.densities)
        self.env_config()  # the config fields, the grid and the decision period
        return self

    def env_config(self) -> MiVeCCConfig:
        """The training environments' config (``ConfigError`` for a bad field)."""
        for name in ("rows", "cols", "control", "max_steps"):
            if name in self.config:
                raise ConfigError(f"config: {name} is set by the training settings, not by "
                                  "a config field")
        cfg = from_overrides(None, **{**self.config, "rows": self.rows, "cols": self.cols,
                                      "control": "signalized",
                                      "max_steps": self.episode_steps})
        period = decision_steps(self.decision_period_s, cfg.dt_s)
        if period > self.episode_steps:
            raise ConfigError(f"episode_steps: must hold at least one decision "
                              f"({period} steps), got {self.episode_steps}")
        return cfg

    def to_dict(self) -> dict[str, Any]:
        """Plain values (for checkpoints and logs)."""
        return plain_dict(self)


def decision_steps(period_s: float, dt_s: float) -> int:
    """Env steps per decision, or ``ConfigError`` if ``period_s`` is not a whole number of
    steps of ``dt_s`` (>= 1)."""
    steps = round(period_s / dt_s)
    if steps < 1 or abs(steps * dt_s - period_s) > 1e-9 * max(1.0, period_s):
        raise ConfigError(f"decision_period_s: must be a whole number >= 1 of steps of "
                          f"{dt_s} s, got {period_s!r}")
    return steps


def plain_dict(settings: Any) -> dict[str, Any]:
    """A settings dataclass as plain values (for checkpoints and logs; densities a list)."""
    data = dataclasses.asdict(settings)
    data["densities"] = list(data["densities"])
    return data


def check_numbers(settings: Any, ints: dict[str, tuple[int, int]],
                  floats: dict[str, tuple[float, float, bool]]) -> None:
    """:class:`ConfigError` naming the first field of ``settings`` out of its range.

    Args:
        ints: field -> (lo, hi): an integer in ``[lo, hi]``.
        floats: field -> (lo, hi, lo_open): a finite number in ``[lo, hi]`` (``(lo, hi]`` if
            ``lo_open``).
    """
    for name, (lo, hi) in ints.items():
        value = getattr(settings, name)
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or not (
                lo <= value <= hi):
            raise ConfigError(f"{name}: must be an integer in [{lo}, {hi}], got {value!r}")
    for name, (lo, hi, lo_open) in floats.items():
        value = getattr(settings, name)
        ok = isinstance(value, int | float | np.number) and not isinstance(value, bool)
        ok = ok and math.isfinite(value) and (lo < value if lo_open else lo <= value)
        if not (ok and value <= hi):
            bracket = "(" if lo_open else "["
            raise ConfigError(f"{name}: must be a number in {bracket}{lo}, {hi}], "
                              f"got {value!r}")


def check_densities(densities: Any) -> None:
    """:class:`ConfigError` unless ``densities`` is one or more demands in (0, 10000]."""
    if not densities or not all(
            isinstance(d, int | float) and not isinstance(d, bool) and 0 < d <= 10_000
            for d in densities):
        raise ConfigError("densities: must be one or more numbers in (0, 10000] "
                          f"[veh/lane/h], got {densities!r}")
