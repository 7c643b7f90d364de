"""Training hyper-parameter presets.

``released``: the authors' released trainer (``docs/training.md`` lists each difference and its
field): constant learning rates 1e-3 / 1e-2, one update per collected frame after a warm-up,
one scalar exploration noise N(0, 0.1^2) per environment and step for the edge stage and none for
the cloud, the raw edge action executed on every other step, one continuing simulation per
environment cut into chunks (3000 steps edge, 1000 cloud), the released reward form and networks.
``paper``: the values of the paper's table (Section VII): Adam, lr actor 1e-3 and critic 0.05,
both decayed linearly to 0, gamma 0.8, minibatch 48, soft update tau 0.01 ("0.99": the target
keeps 99 % per update), 0.5 updates per frame. ``stable``: learning rates that Adam can use
(actor 1e-4, critic 1e-3), gradient clipping, and minibatch 192 with 0.125 updates per frame:
the same 24 replayed samples per collected frame as ``paper`` in 4x fewer, 4x larger updates
(the update is per-call-overhead bound on CPU, so this is ~3x faster). See
``docs/training.md`` for the measurements behind the default.
"""

from __future__ import annotations

import dataclasses
import math
import os
import typing
from dataclasses import dataclass
from typing import Any, Literal

from mivecc_env.config import MiVeCCConfig, Range, check_range, field_range

__all__ = [
    "DEFAULT_PRESET",
    "PRESETS",
    "TrainPreset",
    "add_train_arguments",
    "check_uniform_exploration",
    "get_preset",
    "preset_with",
    "thread_settings",
]


@dataclass(frozen=True)
class TrainPreset:
    """DDPG hyper-parameters.

    Attributes:
        name: Preset name.
        lr_actor: Initial actor learning rate (decayed linearly to 0 over the run).
        lr_critic: Initial critic learning rate (decayed linearly to 0 over the run).
        gamma: Discount factor.
        batch_size: Minibatch size [transitions].
        tau: Soft-update rate of the target networks (target keeps ``1 - tau``).
        sigma_init: Initial std of the Gaussian exploration noise [m/s^2].
        sigma_end: Final std of the noise [m/s^2] (reached after ``sigma_anneal_fraction``).
        sigma_anneal_fraction: Fraction of the run over which sigma is annealed.
        frames_per_batch: Steps of each environment per iteration (an iteration collects
            ``frames_per_batch x`` the number of environments frames, then learns).
        updates_per_frame: Gradient updates per collected frame (``updates_per_frame x
            batch_size`` is the number of replayed samples per collected frame).
        envs: Environments of the native batched env, split evenly across the training
            densities (``envs // len(densities)`` each, at least 1): stage I with 3 densities
            runs 3 x 16, stage II with one density 48 (the ``pettingzoo`` backend has one
            environment per density).
        envs_per_density: Environments per density, overriding ``envs`` (``None``: from
            ``envs``).
        warmup_frames: Transitions in the buffer before learning starts.
        buffer_size: Replay capacity [transitions] (capped by ``buffer_memory_mb``).
        buffer_memory_mb: Memory cap of the replay storage [MiB].
        max_grad_norm: Gradient clipping (``None``: no clipping).
        episode_steps: Steps per episode (env ``max_steps``); 3000 = 300 s at 0.1 s. With
            ``continuous`` the length of a chunk.
        lr_schedule: ``"linear"``: both learning rates decay linearly to 0 over the run;
            ``"constant"``: they stay (the released trainer: its printed decay never reaches
            the optimiser).
        exploration: ``"per_column"``: independent Gaussian noise per action column, sigma
            annealed from ``sigma_init`` to ``sigma_end``; ``"scalar"``: one Gaussian number
            per environment and step added to all its actions (released edge stage, sigma
            annealed the same way); ``"none"``: no noise (released cloud stage).
        explore_uniform_prob: After the noise, each action column is replaced, with this
            probability, by a uniform draw over [-3, 3] m/s^2 (every step, not annealed; 0:
            never). Keeps showing the critic every action where the actor sits at a bound;
            needs noise (not ``exploration="none"``).
        raw_edge_period: Stage I: on every ``n``-th step the edge action is executed
            unmodified (no veto, no max; released: 2, every other step); 0: never.
        continuous: One continuing simulation per environment, episodes are chunks of
            ``episode_steps`` (truncation without reset); ``False``: every episode starts
            from an empty network.
        network: Network variant, ``"paper"`` (the paper's table), ``"released"`` or
            ``"per_pick"`` (one MLP shared by every column;
            :class:`mivecc_agents.networks.NetworkSpec`).
        env_overrides: Env config fields the preset sets for training, as ``(name, value)``
            pairs (reward form, training-time edge selection); explicit ``--set`` wins.
        cloud_changes: Fields that differ in stage II, as ``(name, value)`` pairs
            (:meth:`for_stage`).
        eval_every_frames: Every this many frames (and before the first update and at the
            end), evaluate the actor deterministically against its stage's baseline
            (:mod:`mivecc_agents.train_eval`: ``eval_log.csv``, ``eval_curve.png``); 0: never.
        eval_steps: Steps of each evaluation episode.
        eval_seeds: Evaluation seeds per density (seeds ``EVAL_SEED0, EVAL_SEED0 + 1, ...``,
            apart from the training seeds).
        eval_rows, eval_cols: Grid of the periodic evaluation (``None``: the training grid),
            e.g. the 3x3 grid of the paper's table for an edge trained on 1x1.
        eval_select: Which evaluation ``<stage>_best.pt`` keeps: ``"mean_gain"``, the
            highest mean gain over the densities [%]; ``"min_ceiling_share"``, the highest
            smallest share of the constant +3 ceiling's gain over the densities [%] (the
            policy's weakest density measured against what a constant action reaches there).
        actor_preact_bound: Keep the actor's pre-tanh outputs ``z`` within this bound by adding
            ``actor_preact_weight x`` the mean squared excess ``max(|z| - bound, 0)^2`` to the
            loss (:func:`mivecc_agents.learner.preactivation_penalty`); ``None``: no penalty
            (the released trainer; its clouds saturate, ``docs/training.md``).
        actor_preact_weight: Weight of that penalty (>= 0).
        actor_init_action: Start the actor near this action [m/s^2] in every column: its output
            layer's bias is set to ``atanh(a / 3)`` (the weights keep their initialisation, so
            the actions start spread around it); ``None``: the usual initialisation. Warm-starts
            the policy at a constant coordinator (e.g. +2.9, just inside the +3 bound where the
            tanh still has a gradient) for training to improve on.
        reward_shaping: ``"none"``: the env's reward; ``"potential"``: the trained group's
            reward plus ``gamma Phi(s') - Phi(s)`` with ``Phi(s)`` = the reward's velocity
            term in ``s`` / (1 - gamma) (:mod:`mivecc_agents.reward_shaping`: the same optimal
            policies, without the speed level the critic would otherwise have to learn).
        algorithm: ``"ddpg"``: TorchRL ``DDPGLoss`` (one critic; the paper's and the
            released trainer's); ``"td3"``: TorchRL ``TD3Loss`` (Fujimoto et al. 2018: two
            critics, the target from the smaller, noise on the target action, delayed actor
            and target updates), against a critic that overrates the actor's own action.
        td3_target_noise: TD3 only: std of the Gaussian noise on the target actor's action
            [m/s^2] (TD3's 0.2 of the action bound).
        td3_noise_clip: TD3 only: that noise is clipped to +-this [m/s^2] (TD3's 0.5 of the
            bound).
        td3_policy_delay: TD3 only: critic updates per actor and target update (TD3's 2).
        critic_members: DDPG only: critics trained side by side, each on its own TD(0) target
            from its own target copy, the actor climbing their mean
            (:class:`mivecc_agents.networks.CriticEnsembleNet`): an ensemble against one
            critic's fitting noise, which ranks the actor's own action above better ones in
            some training seeds and not in others (``docs/training.md``); 1: DDPG's one critic.
    """

    name: str
    lr_actor: float
    lr_critic: float
    gamma: float = 0.8
    batch_size: int = 48
    tau: float = 0.01
    sigma_init: float = 1.0
    sigma_end: float = 0.1
    sigma_anneal_fraction: float = 0.8
    frames_per_batch: int = 100
    updates_per_frame: float = 0.5
    envs: int = 48
    envs_per_density: int | None = None
    warmup_frames: int = 480
    buffer_size: int = 100_000
    buffer_memory_mb: int = 1024
    max_grad_norm: float | None = None
    episode_steps: int = 3000
    lr_schedule: Literal["linear", "constant"] = "linear"
    exploration: Literal["per_column", "scalar", "none"] = "per_column"
    explore_uniform_prob: float = 0.0
    raw_edge_period: int = 0
    continuous: bool = False
    network: Literal["paper", "released", "per_pick"] = "paper"
    env_overrides: tuple[tuple[str, Any], ...] = ()
    cloud_changes: tuple[tuple[str, Any], ...] = ()
    eval_every_frames: int = 0
    eval_steps: int = 1500
    eval_seeds: int = 1
    eval_rows: int | None = None
    eval_cols: int | None = None
    eval_select: Literal["mean_gain", "min_ceiling_share"] = "mean_gain"
    actor_preact_bound: float | None = None
    actor_preact_weight: float = 1.0
    actor_init_action: float | None = None
    reward_shaping: Literal["none", "potential"] = "none"
    algorithm: Literal["ddpg", "td3"] = "ddpg"
    td3_target_noise: float = 0.6
    td3_noise_clip: float = 1.5
    td3_policy_delay: int = 2
    critic_members: int = 1

    def __post_init__(self) -> None:
        for name, rng in _FIELD_RANGES.items():
            check_range(name, getattr(self, name), rng, optional=name in _OPTIONAL_FIELDS)
        if not (math.isfinite(self.gamma) and 0.0 <= self.gamma <= 1.0):
            raise ValueError(f"gamma: must be a number in [0, 1], got {self.gamma!r}")
        if self.reward_shaping == "potential" and self.gamma == 1.0:
            raise ValueError("reward_shaping: 'potential' needs gamma < 1 (its potential is "
                             "the velocity term / (1 - gamma)), got gamma 1.0")
        bound = self.actor_preact_bound
        if bound is not None and not (math.isfinite(bound) and bound > 0):
            raise ValueError(f"actor_preact_bound: must be a finite number > 0 or none, "
                             f"got {bound!r}")
        check_uniform_exploration(self.exploration, self.explore_uniform_prob)
        if self.algorithm == "td3" and self.critic_members != 1:
            raise ValueError(f"critic_members: must be 1 with algorithm 'td3' (it has its own "
                             f"pair of critics), got {self.critic_members}")
        if not (math.isfinite(self.actor_preact_weight) and self.actor_preact_weight >= 0):
            raise ValueError(f"actor_preact_weight: must be a finite number >= 0, "
                             f"got {self.actor_preact_weight!r}")

    def for_stage(self, stage: str) -> TrainPreset:
        """The preset as used in a stage (``cloud_changes`` applied in stage II; the raw edge
        action only exists in stage I)."""
        if stage == "cloud":
            return self.replace(**dict(self.cloud_changes), raw_edge_period=0, cloud_changes=())
        return self

    def replace(self, **changes: Any) -> TrainPreset:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Fields as a plain dict."""
        return dataclasses.asdict(self)


def check_uniform_exploration(exploration: str, uniform_prob: float) -> None:
    """Uniform draws replace columns of a noisy action: refuse them without noise.

    Raises:
        ValueError: ``uniform_prob`` > 0 with ``exploration="none"``, naming the field.
    """
    if exploration == "none" and uniform_prob > 0:
        raise ValueError(f"explore_uniform_prob: must be 0 with exploration 'none', got "
                         f"{uniform_prob}")


#: Range of each numeric field (``gamma``, ``actor_preact_bound`` and ``actor_preact_weight``
#: are checked in ``__post_init__`` with their own messages); the optional ones may be None.
_FIELD_RANGES: dict[str, Range] = {
    "lr_actor": Range(0.0, math.inf),
    "lr_critic": Range(0.0, math.inf),
    "batch_size": Range(1, math.inf, integer=True),
    "tau": Range(0.0, 1.0),
    "sigma_init": Range(0.0, math.inf),
    "sigma_end": Range(0.0, math.inf),
    "sigma_anneal_fraction": Range(0.0, 1.0),
    "frames_per_batch": Range(1, math.inf, integer=True),
    "updates_per_frame": Range(0.0, math.inf, lo_open=True),
    "envs": Range(1, math.inf, integer=True),
    "envs_per_density": Range(1, math.inf, integer=True),
    "warmup_frames": Range(0, math.inf, integer=True),
    "buffer_size": Range(1, math.inf, integer=True),
    "buffer_memory_mb": Range(1, math.inf, integer=True),
    "max_grad_norm": Range(0.0, math.inf, lo_open=True),
    "episode_steps": Range(1, math.inf, integer=True),
    "explore_uniform_prob": Range(0.0, 1.0),
    "raw_edge_period": Range(0, math.inf, integer=True),
    "eval_every_frames": Range(0, math.inf, integer=True),
    "eval_steps": Range(1, math.inf, integer=True),
    "eval_seeds": Range(1, math.inf, integer=True),
    "eval_rows": field_range("rows"),
    "eval_cols": field_range("cols"),
    "actor_init_action": Range(-3.0, 3.0, lo_open=True, hi_open=True),
    "td3_target_noise": Range(0.0, math.inf),
    "td3_noise_clip": Range(0.0, math.inf),
    "td3_policy_delay": Range(1, math.inf, integer=True),
    "critic_members": Range(1, 16, integer=True),
}
_OPTIONAL_FIELDS = ("envs_per_density", "max_grad_norm", "actor_init_action", "eval_rows",
                    "eval_cols")


PRESETS: dict[str, TrainPreset] = {
    "paper": TrainPreset(name="paper", lr_actor=1e-3, lr_critic=0.05),
    "stable": TrainPreset(
        name="stable",
        lr_actor=1e-4,
        lr_critic=1e-3,
        max_grad_norm=10.0,
        batch_size=192,
        updates_per_frame=0.125,
    ),
    "released": TrainPreset(
        name="released",
        lr_actor=1e-3,
        lr_critic=1e-2,
        lr_schedule="constant",
        gamma=0.8,
        batch_size=48,
        tau=0.01,
        exploration="scalar",
        sigma_init=0.1,
        sigma_end=0.1,
        raw_edge_period=2,
        continuous=True,
        network="released",
        updates_per_frame=1.0,
        envs=6,
        warmup_frames=5000,
        buffer_size=100_000,
        episode_steps=3000,
        env_overrides=(
            ("edge_selection", "lowest_sv"),  # released training picks the lowest SV
            ("reward_sv_weight", 1.0),
            ("edge_reward_scope", "decisions"),
            ("collision_penalty", 0.0),
        ),
        cloud_changes=(
            ("exploration", "none"),
            ("warmup_frames", 500),
            ("buffer_size", 50_000),
            ("episode_steps", 1000),
            ("envs", 3),
        ),
    ),
}

#: First seed of the periodic evaluation (``eval_seeds`` consecutive seeds).
EVAL_SEED0 = 1000

DEFAULT_PRESET = "stable"
"""Preset used when none is named (the paper's critic lr diverges with Adam; docs/training.md)."""


def get_preset(name: str | TrainPreset) -> TrainPreset:
    """Return a preset by name (or pass a TrainPreset through).

    Raises:
        ValueError: If the name is unknown.
    """
    if isinstance(name, TrainPreset):
        return name
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; expected one of {sorted(PRESETS)}") from None


def preset_with(preset: str | TrainPreset, items: dict[str, Any]) -> TrainPreset:
    """A preset with some fields changed from ``--preset-set KEY=VALUE`` items.

    Values are converted to the field's type (int, float, bool, str; ``none`` for an
    optional field); tuple fields (``env_overrides``, ``cloud_changes``) cannot be set here
    (use ``--set`` for env fields).

    Raises:
        ValueError: an unknown or unsettable field, or a value of the wrong type (the
            message names the field).
    """
    p = get_preset(preset)
    hints = typing.get_type_hints(TrainPreset)
    settable = sorted(k for k in hints if k not in _NOT_SETTABLE)
    changes: dict[str, Any] = {}
    for key, raw in items.items():
        if key not in settable:
            raise ValueError(f"--preset-set: unknown field {key!r}; settable: {settable}")
        try:
            changes[key] = _convert(str(raw).strip(), hints[key])
        except ValueError:
            raise ValueError(
                f"--preset-set {key}: cannot use {raw!r} (expected {_describe(hints[key])})"
            ) from None
    # an explicit change also holds in stage II
    changes["cloud_changes"] = tuple((k, v) for k, v in p.cloud_changes if k not in changes)
    return p.replace(**changes)


_NOT_SETTABLE = ("name", "env_overrides", "cloud_changes")


def _describe(hint: Any) -> str:
    """What a field of type ``hint`` accepts, in words: ``a finite number or none``."""
    options = typing.get_args(hint)
    if typing.get_origin(hint) is Literal:
        return "one of " + ", ".join(map(str, options))
    words = {float: "a finite number", int: "an integer", bool: "true or false"}
    kinds = [words.get(t, getattr(t, "__name__", str(t))) for t in options or (hint,)
             if t is not type(None)]
    return " or ".join(kinds + (["none"] if type(None) in options else []))


def _convert(text: str, hint: Any) -> Any:
    """``text`` as a value of the field type ``hint`` (``ValueError`` if it is not one)."""
    options = typing.get_args(hint)
    if typing.get_origin(hint) is Literal:
        if text not in options:
            raise ValueError(text)
        return text
    if type(None) in options:  # an optional field: "none" or a value of the other type
        if text.lower() == "none":
            return None
        hint = next(t for t in options if t is not type(None))
    if hint is bool:
        if text.lower() not in ("true", "false", "1", "0"):
            raise ValueError(text)
        return text.lower() in ("true", "1")
    value = hint(text)  # int or float
    if not math.isfinite(value):
        raise ValueError(text)
    return value


def add_train_arguments(parser: Any) -> None:
    """Options of ``mivecc train`` (kept here so that ``mivecc --help`` imports no torch)."""
    parser.add_argument("--stage", choices=("edge", "cloud"), default="edge",
                        help="edge: stage I (scheme EE); cloud: stage II (scheme EEC, edge frozen)")
    parser.add_argument("--preset", choices=sorted(PRESETS), default=DEFAULT_PRESET,
                        help=f"hyper-parameters (default {DEFAULT_PRESET})")
    parser.add_argument("--preset-set", dest="preset_items", metavar="KEY=VALUE", nargs="+",
                        action="extend", default=[],
                        help="change preset fields, e.g. --preset-set updates_per_frame=0.25 "
                        "batch_size=192 (docs/training.md lists them)")
    parser.add_argument("--frames", type=int, default=None,
                        help="total env steps (default: 50 episodes per density)")
    parser.add_argument("--episode-steps", type=int, default=None,
                        help="steps per episode (default: the preset's, 3000 = 300 s)")
    parser.add_argument("--rows", type=int, default=None, help="grid rows (edge 1, cloud 3)")
    parser.add_argument("--cols", type=int, default=None, help="grid cols (edge 1, cloud 3)")
    density = MiVeCCConfig.__dataclass_fields__["density_vplh"].default
    parser.add_argument("--density", type=float, nargs="+", default=[density],
                        help=f"training densities [veh/lane/h], one env each (default {density:g})")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/train", help="output folder (default runs/train)")
    parser.add_argument("--resume", default=None, help="checkpoint of this stage to continue")
    parser.add_argument("--edge-checkpoint", default=None,
                        help="stage II: stage-I checkpoint (default: shipped pretrained edge)")
    parser.add_argument("--buffer-size", type=int, default=None, help="replay capacity")
    parser.add_argument("--workers", type=int, default=1,
                        help="collector processes (MultiSyncCollector when > 1)")
    parser.add_argument("--ray-address", default=None,
                        help="ray cluster address (RayCollector; pip install mivecc[ray])")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch threads (default: 1 for edge, 2 for cloud)")
    parser.add_argument("--backend", choices=("native", "pettingzoo"), default="native",
                        help="native: batched TorchRL env (default); pettingzoo: "
                        "PettingZooWrapper + SerialEnv, one env per density")
    parser.add_argument("--envs-per-density", type=int, default=None,
                        help="native backend: environments per density (default: the "
                        "preset's 48 environments split across the densities)")
    parser.add_argument("--device", default="cpu",
                        help="torch device of the learner (networks, optimiser, replay "
                        "buffer), e.g. cuda; collection and checkpoints stay on the CPU "
                        "(default cpu)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+",
                        action="extend", default=[], help="other env config fields")


def thread_settings(stage: str, threads: int | None = None) -> dict[str, str]:
    """Environment variables for torch's OpenMP threads, to set before torch is imported.

    The edge learner is per-call-overhead bound, so stage I uses 1 thread; the cloud learner
    (60x60 convolutions) gains from 2 threads on an idle machine. ``OMP_WAIT_POLICY=PASSIVE``
    makes an idle OpenMP thread sleep instead of spinning: on this shared two-core machine a
    spinning second thread made each update up to 30x slower, a passive one ~1.3x (measured,
    ``docs/training.md``).

    Args:
        stage: ``"edge"`` or ``"cloud"``.
        threads: Explicit thread count (``None``: 1 for edge, ``min(2, cores)`` for cloud).

    Returns:
        ``{"OMP_NUM_THREADS": ..., "OMP_WAIT_POLICY": "PASSIVE"}``.
    """
    if threads is None:
        threads = 1 if stage == "edge" else min(2, os.cpu_count() or 1)
    return {"OMP_NUM_THREADS": str(int(threads)), "OMP_WAIT_POLICY": "PASSIVE"}
