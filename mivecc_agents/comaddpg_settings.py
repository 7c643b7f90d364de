"""Training settings of CoMADDPG (:mod:`mivecc_agents.comaddpg`), without torch.

Kept apart from the trainer so that the ``mivecc`` command line can list them as options without
importing torch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mivecc_agents.signal_dqn_settings import (
    _opt,
    check_choices,
    check_densities,
    check_numbers,
    plain_dict,
)
from mivecc_env.config import ConfigError, MiVeCCConfig, from_overrides
from mivecc_env.vehicle_agents import VEHICLE_AGENT_FIELDS

__all__ = ["VALIDATION_ENVS", "CoMADDPGSettings"]

#: Default validation environments of ``keep_network="best"``: three per training density
#: (docs/comparators.md, "How many validation environments").
VALIDATION_ENVS = 21


@dataclass(frozen=True)
class CoMADDPGSettings:
    """Training settings of :func:`mivecc_agents.comaddpg.train_comaddpg` (each checked by
    :meth:`check`; ``field.metadata["help"]`` says what each one is)."""

    episodes: int = _opt(30, "training episodes; each runs `batch` environments for "
                         "`episode_steps` steps from an empty network")
    batch: int = _opt(7, "environments stepped together")
    episode_steps: int = _opt(1000, "steps of 0.1 s per episode")
    densities: tuple[float, ...] = _opt((300.0, 600.0, 900.0, 1200.0, 1500.0, 1800.0, 2100.0),
                                        "demands [veh/lane/h], cycled over the environments")
    rows: int = _opt(3, "intersection rows of the training grid")
    cols: int = _opt(3, "intersection columns of the training grid")
    k: int = _opt(8, "rows of a vehicle's observation: itself and its k - 1 nearest reference "
                  "vehicles on its virtual lane")
    collision_penalty: float = _opt(20.0, "reward lost by a vehicle that collides (its last "
                                    "transition)")
    safety_weight: float = _opt(2.0, "weight of the safety term min(SV, 0) / 20 of the "
                                "reward (SV: the vehicle's safety value after the step)")
    gamma: float = _opt(0.99, "discount per step of 0.1 s")
    lr_actor: float = _opt(3e-4, "Adam learning rate of the actor")
    lr_critic: float = _opt(1e-3, "Adam learning rate of the critic")
    critic_view: str = _opt("actions", "what the centralised critic sees besides the vehicle's "
                            "observation and action: its references' actions (actions) or "
                            "their actions and observations (observations)",
                            ("actions", "observations"))
    hidden: int = _opt(64, "units of each of the actor's two hidden layers")
    critic_hidden: int = _opt(128, "units of the critic's first hidden layer (the second has "
                              "half)")
    buffer: int = _opt(200_000, "replay buffer size [transitions]")
    minibatch: int = _opt(256, "transitions per update")
    warmup: int = _opt(5_000, "transitions in the buffer before the first update")
    updates_per_step: int = _opt(1, "gradient updates per environment step of the batch")
    tau: float = _opt(0.01, "soft target update rate")
    noise_start: float = _opt(1.0, "standard deviation of the Gaussian exploration noise on "
                              "each vehicle's acceleration at the start [m/s^2]")
    noise_end: float = _opt(0.1, "... after the decay [m/s^2]")
    noise_hold_steps: int = _opt(10, "steps for which a vehicle's exploration noise is held "
                                 "before it is drawn anew")
    noise_decay_fraction: float = _opt(0.6, "share of the steps over which the noise decays "
                                       "linearly")
    seed: int = _opt(0, "seed of the networks, the replay sampling, the exploration and the "
                     "training demand")
    keep_network: str = _opt(
        "best", "which actor the training returns: `best`, of the actors after each episode "
        "once the exploration noise has decayed (and after the last episode), the one whose "
        "greedy run of `validation_steps` on `validation_envs` validation environments "
        "had the fewest strict collision events, ties by the highest average travel velocity; "
        "`last`, the one it ended with (before session 47 the only one)", ("best", "last"))
    validation_steps: int = _opt(3000, "steps of 0.1 s of each validation run (keep_network "
                                 "best; the comparison's runs have 3000)")
    validation_envs: int = _opt(VALIDATION_ENVS, "environments of each validation run "
                                "(keep_network best): `densities` cycled over them, seeds 1000 "
                                "on")
    config: dict[str, Any] = field(default_factory=dict, metadata={
        "help": "further MiVeCCConfig fields of the training environments"})

    def check(self) -> CoMADDPGSettings:
        """Return self, or raise :class:`ConfigError` naming the first bad field and its range."""
        ints = {"episodes": (1, 100_000), "batch": (1, 4096), "episode_steps": (1, 10**7),
                "rows": (1, 20), "cols": (1, 20), "k": (2, 64), "hidden": (1, 4096),
                "critic_hidden": (2, 4096), "buffer": (1, 10**8), "minibatch": (1, 65_536),
                "warmup": (1, 10**8), "updates_per_step": (0, 1000), "seed": (0, 2**31),
                "noise_hold_steps": (1, 10**6), "validation_steps": (1, 10**7),
                "validation_envs": (1, 4096)}
        floats = {"collision_penalty": (0.0, 1e6, False), "safety_weight": (0.0, 1e6, False),
                  "gamma": (0.0, 1.0, False), "lr_actor": (0.0, 1.0, True),
                  "lr_critic": (0.0, 1.0, True), "tau": (0.0, 1.0, True),
                  "noise_start": (0.0, 100.0, False), "noise_end": (0.0, 100.0, False),
                  "noise_decay_fraction": (0.0, 1.0, True)}
        check_numbers(self, ints, floats)
        check_choices(self)
        check_densities(self.densities)
        self.env_config()
        return self

    def env_config(self) -> MiVeCCConfig:
        """The training environments' config (``ConfigError`` for a bad field)."""
        for name in ("rows", "cols", "max_steps", *vehicle_agent_fields()):
            if name in self.config:
                raise ConfigError(f"config: {name} is set by the training settings, not by "
                                  "a config field")
        return from_overrides(None, **{**self.config, **vehicle_agent_fields(),
                                       "rows": self.rows, "cols": self.cols,
                                       "max_steps": self.episode_steps})

    def to_dict(self) -> dict[str, Any]:
        """Plain values (for checkpoints and logs)."""
        return plain_dict(self)


def vehicle_agent_fields() -> dict[str, Any]:
    """A copy of :data:`mivecc_env.vehicle_agents.VEHICLE_AGENT_FIELDS`, the config fields under
    which vehicle agents act."""
    return dict(VEHICLE_AGENT_FIELDS)
