"""Two-stage DDPG training of the MiVeCC coordinators with TorchRL.

Stage I (``stage="edge"``): scheme ``EE``, the edge policy shared by all edge nodes is trained;
the cloud group acts with zeros (ignored by ``EE`` anyway). Stage II (``stage="cloud"``): scheme
``EEC``, the edge policy is loaded from a stage-I checkpoint and frozen (no gradient, no noise),
the cloud policy is trained.

Pipeline: ``PettingZooWrapper`` (groups ``edge`` and ``cloud``) -> ``RenameTransform`` copying
``(g, "info", "mask")`` to ``(g, "mask")`` (root and ``next``) -> ``SerialEnv`` with one env per
training density -> ``Collector`` (``MultiSyncCollector`` with ``workers > 1``, ``RayCollector``
with ``ray_address``) -> ``TensorDictReplayBuffer(LazyTensorStorage)`` holding only the trained
group's keys -> ``DDPGLoss`` (target actor and critic, TD(0), gamma) + ``SoftUpdate`` + Adam with
learning rates decayed linearly to 0 (``LambdaLR``).

Masking: padded columns (no vehicle) are zeroed by the actor, again after the exploration noise,
and the critic multiplies the action by the mask. The critic outputs one value per agent (not
per column), so padded columns enter neither the TD error nor the actor gradient: the plain
mean of DDPGLoss is already the right loss, no masked reduction is needed.

This module runs a training (:func:`train`); its pieces live in :mod:`mivecc_agents.stages`
(stages, groups, ``TrainingError``), :mod:`mivecc_agents.train_envs` (the envs),
:mod:`mivecc_agents.collectors` (the collector), :mod:`mivecc_agents.train_log` (the log and
its figure) and :mod:`mivecc_agents.learner` (the updates). Their public names are also
importable from here.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn

from mivecc_agents.checkpoints import (
    CheckpointError,
    load_checkpoint,
    network_variant,
    save_checkpoint,
)
from mivecc_agents.collectors import make_collector
from mivecc_agents.exploration import make_exploration
from mivecc_agents.learner import DDPGLearner, UpdateStats, make_loss, saturated_share
from mivecc_agents.macro_steps import cloud_macro_transitions
from mivecc_agents.networks import (
    ACTION_SCALE_MPS2,
    critic_members_in,
    make_actor,
    make_critic,
)
from mivecc_agents.presets import DEFAULT_PRESET, TrainPreset, get_preset
from mivecc_agents.reward_shaping import potential_keys, shape_rewards
from mivecc_agents.stages import GROUPS, STAGES, TrainingError
from mivecc_agents.train_envs import (
    density_list,
    env_factory,
    env_groups,
    make_env,
    make_native_env,
    worker_env_fns,
)
from mivecc_agents.train_log import (
    log_fields,
    log_row,
    log_tensorboard,
    open_log,
    plot_learning_curve,
    tensorboard_writer,
)
from mivecc_env.sim.checks import check_int_at_least

__all__ = [
    "GROUPS",
    "STAGES",
    "TrainingError",
    "TrainingInterrupted",
    "env_factory",
    "iteration_frames",
    "make_env",
    "make_loss",
    "make_native_env",
    "make_policy",
    "plot_learning_curve",
    "train",
]

# --------------------------------------------------------------------------------------------
# Policy pieces
class _ZeroAction(nn.Module):
    """Zero accelerations, shaped like the mask ``(..., K)``."""

    def forward(self, mask: torch.Tensor) -> torch.Tensor:
        return torch.zeros_like(mask)


class _Finalize(nn.Module):
    """Clamp to [-3, 3] m/s^2 and zero padded columns (after exploration noise)."""

    def forward(self, action: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return action.clamp(-ACTION_SCALE_MPS2, ACTION_SCALE_MPS2) * mask.to(action.dtype)


def _finalize(group: str) -> TensorDictModule:
    return TensorDictModule(
        _Finalize(), in_keys=[(group, "action"), (group, "mask")], out_keys=[(group, "action")]
    )


def zero_policy(group: str) -> TensorDictModule:
    """A fixed module writing zeros to ``(group, "action")``."""
    return TensorDictModule(_ZeroAction(), in_keys=[(group, "mask")], out_keys=[(group, "action")])


def freeze(module: nn.Module) -> nn.Module:
    """Disable gradients of every parameter (in place) and switch to eval mode."""
    for p in module.parameters():
        p.requires_grad_(False)
    return module.eval()


def make_policy(
    stage: str,
    actor: TensorDictModule,
    noise: nn.Module | None,
    frozen_edge: TensorDictModule | None = None,
    groups: Sequence[str] = GROUPS,
) -> TensorDictSequential:
    """The collection policy: trained actor (+ noise) and the other group's fixed actions
    (stage I writes zero cloud actions only if the env has a ``cloud`` group)."""
    group = STAGES[stage]["group"]
    mods: list[nn.Module] = []
    if stage == "cloud":
        if frozen_edge is None:
            raise TrainingError("stage 'cloud' needs the frozen edge policy")
        mods += [frozen_edge, _finalize("edge")]
    mods.append(actor)
    if noise is not None:
        mods.append(noise)
    mods.append(_finalize(group))
    if stage == "edge" and "cloud" in groups:
        mods.append(zero_policy("cloud"))
    return TensorDictSequential(*mods)


def load_frozen_edge_actor(path: str | Path) -> TensorDictModule:
    """Load the stage-I edge actor, frozen (no grad, eval)."""
    ckpt = load_checkpoint(path, expected_kind="edge")
    actor = make_actor("edge", "edge", variant=network_variant(ckpt))
    actor.module.load_state_dict(ckpt["actor"])
    freeze(actor)
    return actor


# --------------------------------------------------------------------------------------------
def _buffer_keys(group: str) -> list:
    return [
        (group, "observation"),
        (group, "mask"),
        (group, "action"),
        ("next", group, "observation"),
        ("next", group, "mask"),
        ("next", group, "reward"),
        ("next", group, "done"),
        ("next", group, "terminated"),
    ]


def train(*args: Any, **kwargs: Any) -> Path:
    """Train one stage (see :func:`_train` for the arguments); returns the final checkpoint.

    TorchRL's exploration noise, replay sampling and network initialisation draw from torch's
    global generator, so training runs inside ``torch.random.fork_rng``: it is seeded with
    ``seed`` there and the caller's global random state is restored afterwards.

    Raises:
        TrainingInterrupted: Ctrl-C (SIGINT) stopped the run; the checkpoint and the plots were
            saved first (``.checkpoint`` holds the path).
    """
    with torch.random.fork_rng(devices=[]):
        return _train(*args, **kwargs)


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped by Ctrl-C after saving; ``checkpoint`` is the path written."""

    def __init__(self, checkpoint: Path, frames: int) -> None:
        super().__init__(f"interrupted at {frames} frames; checkpoint saved to {checkpoint}")
        self.checkpoint = checkpoint
        self.frames = frames


class _StopOnSigint:
    """First Ctrl-C: set ``requested`` (the loop stops at the next check and saves); a second
    one raises ``KeyboardInterrupt`` at once. Only installed in the main thread."""

    def __init__(self) -> None:
        self.requested = False
        self._old: Any = None

    def __enter__(self) -> _StopOnSigint:
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        import signal
        import sys

        if self.requested:
            signal.signal(signal.SIGINT, self._old or signal.default_int_handler)
            raise KeyboardInterrupt
        self.requested = True
        print("mivecc train: Ctrl-C: saving a checkpoint and the plots after this step "
              "(Ctrl-C again to abort without saving)", file=sys.stderr, flush=True)

    def __exit__(self, *exc: Any) -> None:
        import signal

        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


def learner_device(device: str | torch.device, name: str = "device") -> torch.device:
    """``device`` as a torch device that training can use: the CPU or a CUDA device torch sees.

    Raises:
        TrainingError: naming ``name``, for anything else.
    """
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        dev = None
    if dev is None or dev.type not in ("cpu", "cuda"):
        raise TrainingError(f"{name}: must be cpu, cuda or cuda:N, got {device!r}")
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise TrainingError(f"{name}: {device!r}: torch sees no CUDA device here")
        if dev.index is not None and dev.index >= count:
            raise TrainingError(f"{name}: {device!r}: torch sees {count} CUDA device(s)")
    return dev


def _learner_networks(
    actor: TensorDictModule, critic: TensorDictModule, device: torch.device,
    separate: bool | None = None,
) -> tuple[TensorDictModule, TensorDictModule, Callable[[], None]]:
    """The learner's actor and critic on ``device`` and a function copying the learner's
    actor weights into ``actor`` (which acts in the envs on the CPU). On the CPU both are
    ``actor`` and ``critic`` themselves and the copy does nothing (``separate``: force the
    separate learner actor of another device, for tests)."""
    if not (device.type != "cpu" if separate is None else separate):
        return actor, critic, lambda: None
    import copy

    learn_actor = copy.deepcopy(actor).to(device)

    def sync() -> None:
        with torch.no_grad():
            for dst, src in zip(actor.parameters(), learn_actor.parameters(), strict=True):
                dst.copy_(src)
            for dst, src in zip(actor.buffers(), learn_actor.buffers(), strict=True):
                dst.copy_(src)

    return learn_actor, critic.to(device), sync


def _on_cpu(state: Any) -> Any:
    """A (nested) state dict with every tensor on the CPU (CPU tensors are not copied)."""
    if isinstance(state, torch.Tensor):
        return state.cpu()
    if isinstance(state, dict):
        return {k: _on_cpu(v) for k, v in state.items()}
    if isinstance(state, list | tuple):
        return type(state)(_on_cpu(v) for v in state)
    return state


def _load_start(resume: str | Path, stage: str, group: str) -> dict[str, Any]:
    """Load the checkpoint to resume from; a policy-only export gives a warm start."""
    import sys

    ck = load_checkpoint(resume, expected_kind=group)
    if ck["stage"] != stage:
        raise CheckpointError(f"{resume}: is a {ck['stage']!r}-stage checkpoint, not {stage!r}")
    if "loss" not in ck or "optimizer" not in ck:
        print(
            f"mivecc train: {resume} is a policy-only export (no optimiser or target "
            "networks): warm start from its actor and critic weights, frames count from 0",
            file=sys.stderr,
        )
    return ck


def _stage_preset(
    preset: str | TrainPreset, stage: str, n_densities: int, *, buffer_size: int | None,
    episode_steps: int | None, envs_per_density: int | None,
) -> TrainPreset:
    """The preset of one run: the stage's fields, the run's overrides, and the environments
    per density (the preset's ``envs`` split over the densities unless it names them)."""
    p = get_preset(preset).for_stage(stage)
    if buffer_size is not None:
        p = p.replace(buffer_size=int(buffer_size))
    if episode_steps is not None:
        p = p.replace(episode_steps=int(episode_steps))
    if envs_per_density is not None:
        p = p.replace(envs_per_density=int(envs_per_density))
    if p.envs_per_density is None:
        p = p.replace(envs_per_density=max(1, p.envs // n_densities))
    return p


def _networks_held(p: TrainPreset, start: dict[str, Any] | None, resume: Any) -> TrainPreset:
    """The preset with the network variant and critic count that a resumed checkpoint holds
    (they win over the preset's, with a note on stderr)."""
    import sys

    if start is None:
        return p
    if network_variant(start) != p.network:
        print(f"mivecc train: {resume} holds {network_variant(start)!r} networks: continuing "
              f"with those (the preset names {p.network!r})", file=sys.stderr)
        p = p.replace(network=network_variant(start))
    held = critic_members_in(start["critic"])
    if held != p.critic_members:
        print(f"mivecc train: {resume} holds {held} critic(s): continuing with those (the "
              f"preset names {p.critic_members})", file=sys.stderr)
        p = p.replace(critic_members=held)
    return p


def _actor_critic(
    p: TrainPreset, group: str, start: dict[str, Any] | None, resume: Any,
) -> tuple[TensorDictModule, TensorDictModule, bool]:
    """The trained actor and critic, and whether ``start`` is a warm start (a policy-only
    export: its weights are loaded here; a full checkpoint is loaded into the learner)."""
    actor = make_actor(group, group, variant=p.network)
    if p.actor_init_action is not None and start is None:  # a resumed run keeps its weights
        actor.module.start_near(p.actor_init_action)
    critic = make_critic(group, group, variant=p.network, members=p.critic_members)
    warm = start is not None and "loss" not in start
    if warm:
        try:
            actor.module.load_state_dict(start["actor"])
            critic.module.load_state_dict(start["critic"])
        except (RuntimeError, KeyError) as exc:
            raise CheckpointError(f"{resume}: weights do not fit the {group} networks") from exc
    return actor, critic, warm


def _frozen_edge(
    stage: str, edge_checkpoint: str | Path | None,
) -> tuple[TensorDictModule | None, str | None]:
    """Stage II: the frozen stage-I edge actor and its checkpoint's path (default: the
    shipped edge); stage I: none."""
    if stage != "cloud":
        return None, None
    if edge_checkpoint is None:
        from mivecc_agents.policies import pretrained_path

        edge_checkpoint = pretrained_path("edge")
        if edge_checkpoint is None:
            raise TrainingError(
                "stage 'cloud' needs a stage-I edge checkpoint (edge_checkpoint=...)"
            )
    return load_frozen_edge_actor(edge_checkpoint), str(edge_checkpoint)


def _make_learner(
    actor: TensorDictModule, critic: TensorDictModule, p: TrainPreset, group: str,
    device: torch.device, progress: Callable[[], float],
) -> tuple[DDPGLearner, Callable[[], None]]:
    """The learner on ``device`` (TD3: with its second critic) and the function copying its
    actor's weights into ``actor``, which acts in the envs on the CPU."""
    learn_actor, learn_critic, sync_actor = _learner_networks(actor, critic, device)
    twin = (make_critic(group, group, variant=p.network).to(device)
            if p.algorithm == "td3" else None)  # TD3's second critic, its own initialisation
    learner = DDPGLearner(learn_actor, learn_critic, group, p, progress=progress, twin=twin)
    return learner, sync_actor


def iteration_frames(
    frames_per_batch: int, remaining: int, n_envs: int, workers: int, cloud_period: int,
) -> int:
    """Frames that all collector workers together collect per iteration: whole steps of every
    worker's ``n_envs`` environments, the preset's ``frames_per_batch`` steps per environment
    (fewer if the ``remaining`` frames need fewer) shared by the workers, and whole cloud
    decision blocks of ``cloud_period`` steps per worker."""
    n_workers = max(1, workers)
    steps = -(-max(1, min(frames_per_batch, -(-remaining // n_envs))) // n_workers)
    if cloud_period > 1:  # whole decision blocks per batch (cloud_macro_transitions)
        steps = cloud_period * max(1, steps // cloud_period)
    return n_workers * n_envs * steps


def _replay_buffer(
    p: TrainPreset, probe: Any, policy: TensorDictSequential, keys: list, device: torch.device,
) -> tuple[Any, int, int]:
    """The replay buffer on ``device``, sized on purpose: the preset's ``buffer_size``
    transitions unless they would take more than ``buffer_memory_mb`` (a transition's bytes
    measured on one step of ``probe``, which is closed here). Returns ``(buffer, capacity,
    bytes per transition)``."""
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

    with torch.no_grad():
        sample = probe.rollout(1, policy)
    probe.close()
    per_transition = sum(
        t.numel() * t.element_size() for t in sample.select(*keys).reshape(-1)[0].values(True, True)
    )
    cap_mem = int(p.buffer_memory_mb * 2**20 // max(per_transition, 1))
    capacity = max(p.batch_size, min(p.buffer_size, cap_mem))
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(capacity, device=device),
                                    batch_size=p.batch_size)
    return buffer, capacity, per_transition


def _transitions(
    data: TensorDictBase, group: str, keys: list, p: TrainPreset, cloud_period: int,
) -> TensorDictBase:
    """The replay buffer's transitions (flat, only ``keys``) from one collected batch: one
    per decision of a cloud deciding every ``cloud_period`` steps, the rewards shaped by the
    preset's ``reward_shaping`` (a new reward tensor: ``data`` keeps the raw one)."""
    shaping = p.reward_shaping == "potential"
    collect_keys = keys + potential_keys(group) if shaping else keys
    if cloud_period > 1:
        batch = cloud_macro_transitions(data, cloud_period, collect_keys)
    else:
        batch = data.select(*collect_keys)
    if shaping:
        batch = shape_rewards(batch, group, p.gamma)
    return batch.select(*keys).reshape(-1)


class _RunCheckpoints:
    """A run's checkpoint (``<stage>.pt``), with the run's metadata, and the best policy of
    the periodic evaluation (``<stage>_best.pt``)."""

    def __init__(self, out_dir: Path, stage: str, meta: dict[str, Any], actor: TensorDictModule,
                 learner: DDPGLearner, state: dict[str, int]) -> None:
        self.path = out_dir / f"{stage}.pt"
        self.best_path = out_dir / f"{stage}_best.pt"
        self.meta, self.actor, self.learner, self.state = meta, actor, learner, state

    def save(self, metrics: dict[str, Any], path: Path | None = None, slim: bool = False) -> Path:
        """Write the checkpoint (``path``: elsewhere); ``slim``: without the optimiser and
        target copies (it loads with ``load_policy`` but cannot be resumed)."""
        return save_checkpoint(
            self.path if path is None else path,
            {
                **self.meta,
                "actor": self.actor.module.state_dict(),
                "critic": _on_cpu(self.learner.critic_state_dict()),
                **({} if slim else _on_cpu(self.learner.state_dict())),
                "frames": self.state["frames"],
                "updates": self.state["updates"],
                "metrics": {**metrics, "iteration": self.state["iteration"]},
            },
        )


class _EvaluationSchedule:
    """The periodic evaluation of a run (``evaluate`` None: off): due every
    ``eval_every_frames``; the best policy so far, by ``eval_select``, saved slim."""

    def __init__(self, evaluate: Any, p: TrainPreset, checkpoints: _RunCheckpoints,
                 state: dict[str, int], continuing: bool) -> None:
        self.evaluate, self.p, self.checkpoints, self.state = evaluate, p, checkpoints, state
        self.next_eval, self.last_eval = state["frames"], None
        self.best_score = (_best_score(checkpoints.best_path, p.eval_select) if continuing
                           else -math.inf)

    def maybe(self, bar: Any, progress: bool, final: bool = False) -> None:
        """Evaluate when due; ``final``: unless the current weights were just evaluated."""
        frames = self.state["frames"]
        due = frames != self.last_eval if final else frames >= self.next_eval
        if self.evaluate is None or not due:
            return
        self.last_eval = frames
        scores = self.evaluate(self.checkpoints.actor.module, frames, self.state["updates"])
        score = scores.score(self.p.eval_select)
        if score > self.best_score:  # NaN (no baseline velocity) never counts as better
            self.best_score = score
            self.checkpoints.save({"eval_gain_pct": scores.mean_gain_pct,
                                   "eval_min_ceiling_share_pct": scores.min_ceiling_share_pct,
                                   "eval_select": self.p.eval_select, "eval_score": score},
                                  self.checkpoints.best_path, slim=True)
        if progress:
            import sys

            bar.write(f"eval at {frames} frames: {self.evaluate.scheme} gain "
                      f"{scores.mean_gain_pct:+.2f} %, at least "
                      f"{scores.min_ceiling_share_pct:.0f} % of the +3 ceiling's", file=sys.stderr)
        self.next_eval = frames + self.p.eval_every_frames


def _check_counts(**counts: tuple[Any, int, bool]) -> None:
    """Raise :class:`TrainingError` naming the first argument that is not an integer at least
    its lower bound (``name=(value, low, none_ok)``; ``None`` passes where ``none_ok``)."""
    for name, (value, low, none_ok) in counts.items():
        if value is None and none_ok:
            continue
        try:
            check_int_at_least(name, value, low)
        except ValueError as exc:
            raise TrainingError(str(exc)) from None


def _train(
    stage: str = "edge",
    preset: str | TrainPreset = DEFAULT_PRESET,
    frames: int | None = None,
    rows: int = 1,
    cols: int = 1,
    densities: float | Sequence[float] = 900.0,
    seed: int = 0,
    out_dir: str | Path = "runs/train",
    resume: str | Path | None = None,
    workers: int = 1,
    ray_address: str | None = None,
    progress: bool = True,
    *,
    edge_checkpoint: str | Path | None = None,
    config_overrides: dict[str, Any] | None = None,
    episode_steps: int | None = None,
    buffer_size: int | None = None,
    save_every: int = 50,
    backend: str = "native",
    envs_per_density: int | None = None,
    device: str | torch.device = "cpu",
) -> Path:
    """Train one stage and return the path of the final checkpoint.

    Args:
        stage: ``"edge"`` (stage I, scheme EE) or ``"cloud"`` (stage II, scheme EEC).
        preset: Preset name or :class:`TrainPreset`.
        frames: Total env steps (summed over all environments); default 50 episodes per
            density.
        rows, cols: Grid size.
        densities: One or several arrival densities [veh/lane/h], trained together.
        seed: Seed of torch and the envs.
        out_dir: Output folder (``train_log.csv``, ``learning_curve.png``, ``<stage>.pt``).
        resume: Checkpoint of this stage to continue from (frames count continues); a
            policy-only export (``export_policy``, the shipped policies) is a warm start.
        workers: Collector processes (``MultiSyncCollector`` when > 1).
        ray_address: Collect with ``RayCollector`` (``workers`` remote collectors, 1 CPU each;
            needs ``pip install mivecc[ray]``): ``"local"`` starts a local Ray instance,
            ``"auto"``, ``"host:port"`` or ``"ray://host:port"`` connect to a cluster.
        progress: Show a tqdm progress bar.
        edge_checkpoint: Stage II: the stage-I checkpoint (default: shipped pretrained edge).
        config_overrides: Extra env config fields.
        episode_steps: Steps per episode (default: the preset's).
        buffer_size: Replay capacity override [transitions].
        save_every: Save a checkpoint every this many iterations (0: only the final one).
        backend: ``"native"`` (batched TorchRL env, default) or ``"pettingzoo"`` (the
            PettingZooWrapper + SerialEnv path, one env per density).
        envs_per_density: Native backend: environments per density (default: the preset's
            ``envs_per_density``, else its ``envs`` split across the densities).
        device: Torch device of the learner: the trained actor and critic, their targets and
            optimiser, and the replay buffer. Collection (envs and the policy acting in them),
            the periodic evaluation and the saved checkpoints stay on the CPU: the collection
            actor is a CPU copy of the learner's, updated after each iteration's updates.
            ``"cpu"`` (default) is one actor for both, as before.

    Returns:
        Path of the checkpoint written at the end.
    """
    from tqdm.auto import tqdm

    if stage not in STAGES:
        raise TrainingError(f"unknown stage {stage!r}; expected 'edge' or 'cloud'")
    _check_counts(frames=(frames, 1, True), seed=(seed, 0, False), workers=(workers, 1, False),
                  save_every=(save_every, 0, False))
    if Path(out_dir).exists() and not Path(out_dir).is_dir():
        raise TrainingError(f"out_dir: {str(out_dir)!r} is a file, not a folder")
    device = learner_device(device)
    group, scheme = STAGES[stage]["group"], STAGES[stage]["scheme"]
    dens = density_list(densities)
    p = _stage_preset(preset, stage, len(dens), buffer_size=buffer_size,
                      episode_steps=episode_steps, envs_per_density=envs_per_density)
    overrides = {
        **dict(p.env_overrides),
        **(config_overrides or {}),
        "rows": rows,
        "cols": cols,
        "max_steps": p.episode_steps,
    }
    env_options = _env_options(p)
    env_fn, env_density = env_factory(
        backend, dens, overrides, scheme, p.envs_per_density, seed, env_options
    )
    n_envs = len(env_density)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    total_frames = int(frames) if frames is not None else 50 * p.episode_steps * len(dens)
    torch.manual_seed(seed)

    # --- networks, learner (in this order: each draws its initial weights from torch) ------
    start = _load_start(resume, stage, group) if resume is not None else None
    p = _networks_held(p, start, resume)
    actor, critic, warm = _actor_critic(p, group, start, resume)
    frozen_edge, edge_ckpt_path = _frozen_edge(stage, edge_checkpoint)
    state = {"frames": 0, "updates": 0, "iteration": 0}
    learner, sync_actor = _make_learner(actor, critic, p, group, device,
                                        lambda: state["frames"] / max(total_frames, 1))
    if start is not None and not warm:
        learner.load_state_dict(start)
        sync_actor()
        state.update(
            frames=int(start["frames"]),
            updates=int(start["updates"]),
            iteration=int(start.get("metrics", {}).get("iteration", 0)),
        )
        learner.updates = state["updates"]

    # --- exploration policy, frames per iteration, replay buffer ---------------------------
    probe = env_fn()
    noise = make_exploration(
        p.exploration,
        probe.full_action_spec[(group, "action")].clone(),
        p.sigma_init,
        p.sigma_end,
        p.sigma_anneal_fraction * total_frames,
        (group, "action"),
        uniform_prob=p.explore_uniform_prob,
    )
    if state["frames"] and noise is not None:
        noise.step(state["frames"])
    policy = make_policy(stage, actor, noise, frozen_edge, groups=env_groups(probe))
    remaining = max(0, total_frames - state["frames"])
    cloud_period = _cloud_period(stage, overrides, dens[0])
    fpb = iteration_frames(p.frames_per_batch, remaining, n_envs, workers, cloud_period)
    keys = _buffer_keys(group)
    buffer, capacity, per_transition = _replay_buffer(p, probe, policy, keys, device)

    # --- log, checkpoints, periodic evaluation -------------------------------------------
    csv_path = out_dir / "train_log.csv"
    append_logs = resume is not None and not warm and csv_path.exists()  # continuing a run
    fh, writer = open_log(csv_path, log_fields(dens), append=append_logs)
    tb = tensorboard_writer(out_dir)
    meta = {
        "stage": stage,
        "kind": group,
        "grid_size": int(actor.module.spec.grid_size),
        "network": p.network,
        "preset": p.to_dict(),
        "config": _config_dict(overrides, scheme, dens),
        "extra": {
            "edge_checkpoint": edge_ckpt_path,
            "densities": dens,
            "seed": seed,
            "backend": backend,
            "n_envs": n_envs,
            "buffer_capacity": capacity,
            "bytes_per_transition": per_transition,
            "warm_start_from": str(resume) if warm else None,
            "learner_device": str(device),
        },
    }
    checkpoints = _RunCheckpoints(out_dir, stage, meta, actor, learner, state)
    evaluations = _EvaluationSchedule(
        _periodic_evaluation(p, stage, rows, cols, dens, config_overrides or {}, out_dir,
                             edge_ckpt_path, append=append_logs),
        p, checkpoints, state, continuing=append_logs)

    # --- collect and learn ---------------------------------------------------------------
    metrics: dict[str, float] = {}
    episodes = 0
    t0 = time.perf_counter()
    bar = tqdm(
        total=total_frames,
        initial=state["frames"],
        disable=not progress,
        desc=f"train {stage}",
        unit="frame",
    )
    stop = _StopOnSigint()
    with stop:
        collector = None
        try:
            evaluations.maybe(bar, progress)
            if remaining > 0 and not stop.requested:
                collector = make_collector(
                    worker_env_fns(backend, dens, overrides, scheme, p, seed, state, workers,
                                   env_options),
                    policy, fpb, remaining, workers, ray_address,
                )
                if backend == "pettingzoo":  # the native envs are seeded by their factories
                    collector.set_seed(seed + state["frames"])
                t_last = time.perf_counter()
                for data in collector:  # the collector's own buffer: nothing keeps it
                    t_col = time.perf_counter() - t_last
                    n = data.numel()
                    state["frames"] += n
                    state["iteration"] += 1
                    buffer.extend(_transitions(data, group, keys, p, cloud_period))
                    if noise is not None:
                        noise.step(n)
                    stats = UpdateStats()
                    if len(buffer) >= max(p.warmup_frames, p.batch_size):
                        n_upd = max(1, round(p.updates_per_frame * n))
                        stats = learner.update(buffer, n_upd, lambda: stop.requested)
                        state["updates"] += stats.n_updates
                        sync_actor()
                    if workers > 1 or ray_address is not None:
                        collector.update_policy_weights_()
                    metrics = log_row(
                        data,
                        group=group,
                        densities=dens,
                        env_density=env_density,
                        state=state,
                        episodes=episodes,
                        stats=stats,
                        lr=learner.lr(),
                        noise=noise,
                        frames_in_batch=n,
                        collect_s=t_col,
                        buffer_len=len(buffer),
                        wall_s=time.perf_counter() - t0,
                        batch_size=p.batch_size,
                    )
                    metrics["actor_saturated"] = saturated_share(
                        actor.module, data[group, "observation"], data[group, "mask"])
                    episodes = int(metrics["episodes"])
                    writer.writerow(metrics)
                    fh.flush()
                    log_tensorboard(tb, stage, metrics)
                    bar.update(n)
                    bar.set_postfix(
                        v=f"{metrics['avg_velocity_mps']:.2f}",
                        qloss=f"{metrics['critic_loss']:.3g}",
                    )
                    if stop.requested:
                        break
                    if save_every and state["iteration"] % save_every == 0:
                        checkpoints.save(metrics)
                    evaluations.maybe(bar, progress)
                    t_last = time.perf_counter()
            if not stop.requested:
                evaluations.maybe(bar, progress, final=True)
        finally:
            if collector is not None:
                with contextlib.suppress(Exception):  # an interrupted worker may be gone
                    collector.shutdown()
            bar.close()
            fh.close()
            if tb is not None:
                tb.close()
        path = checkpoints.save(metrics)
        plot_learning_curve(csv_path, out_dir / "learning_curve.png")
    if stop.requested:
        raise TrainingInterrupted(path, state["frames"])
    return path


def _best_score(path: Path, select: str) -> float:
    """The ``select`` score [%] a run's best-policy checkpoint records (``-inf``: none yet,
    or it was picked by another rule; a checkpoint from before ``eval_select`` existed was
    picked by the mean gain)."""
    if not path.exists():
        return -math.inf
    metrics = load_checkpoint(path)["metrics"]
    if metrics.get("eval_select", "mean_gain") != select:
        return -math.inf
    return float(metrics.get("eval_score", metrics.get("eval_gain_pct", -math.inf)))


def _periodic_evaluation(
    p: TrainPreset, stage: str, rows: int, cols: int, dens: list[float],
    config_overrides: dict[str, Any], out_dir: Path, edge_checkpoint: str | None, append: bool,
) -> Any:
    """The preset's :class:`~mivecc_agents.train_eval.PeriodicEvaluation` (``None``: off)."""
    if p.eval_every_frames <= 0:
        return None
    from mivecc_agents.policies import load_policy
    from mivecc_agents.presets import EVAL_SEED0
    from mivecc_agents.train_eval import PeriodicEvaluation

    edge = load_policy(edge_checkpoint, "edge") if stage == "cloud" else None
    rows, cols = p.eval_rows or rows, p.eval_cols or cols  # None: the training grid
    return PeriodicEvaluation(
        stage, rows, cols, dens, range(EVAL_SEED0, EVAL_SEED0 + max(1, p.eval_seeds)),
        p.eval_steps, config_overrides, out_dir, edge_policy=edge, append=append,
    )


def _cloud_period(stage: str, overrides: dict[str, Any], density: float) -> int:
    """The env's ``cloud_period`` in stage II (1 in stage I: no cloud acts)."""
    if stage != "cloud":
        return 1
    from mivecc_env.config import from_overrides

    return int(from_overrides(None, **{**overrides, "density": density}).cloud_period)


def _env_options(p: TrainPreset) -> dict[str, Any]:
    """The native env's options a preset asks for (continuous chunks, raw edge steps)."""
    return {"continuous": p.continuous, "raw_edge_period": p.raw_edge_period}


def _config_dict(overrides: dict[str, Any], scheme: str, dens: list[float]) -> dict[str, Any]:
    from mivecc_env.config import from_overrides

    return from_overrides(None, **{**overrides, "scheme": scheme, "density": dens[0]}).to_dict()


# --------------------------------------------------------------------------------------------
# Command line (``mivecc train``)
def train_from_args(args) -> int:
    """Run :func:`train` from parsed ``mivecc train`` options; returns the exit status."""
    import os
    import sys

    from mivecc_agents.cli import parse_set_items
    from mivecc_agents.presets import preset_with, thread_settings
    from mivecc_env.config import ConfigError

    threads = thread_settings(args.stage, args.threads)["OMP_NUM_THREADS"]
    if args.threads is None:  # an OMP_NUM_THREADS of the caller wins over the default
        threads = os.environ.get("OMP_NUM_THREADS", threads)
    torch.set_num_threads(int(threads))
    default = 1 if args.stage == "edge" else 3
    try:
        preset = preset_with(args.preset, parse_set_items(args.preset_items))
    except (ValueError, ConfigError) as exc:
        print(f"mivecc train: error: {exc}", file=sys.stderr)
        return 2
    try:
        device = learner_device(args.device, "--device")
        path = train(
            args.stage, preset, args.frames,
            rows=args.rows or default, cols=args.cols or default, densities=args.density,
            seed=args.seed, out_dir=args.out, resume=args.resume, workers=args.workers,
            ray_address=args.ray_address, progress=not args.no_progress,
            edge_checkpoint=args.edge_checkpoint, config_overrides=parse_set_items(args.set_items),
            episode_steps=args.episode_steps, buffer_size=args.buffer_size,
            backend=args.backend, envs_per_density=args.envs_per_density, device=device,
        )
    except (TrainingError, CheckpointError) as exc:
        print(f"mivecc train: error: {exc}", file=sys.stderr)
        return 2
    except TrainingInterrupted as exc:
        print(f"mivecc train: {exc}", file=sys.stderr)
        print(exc.checkpoint)
        return 130
    print(path)
    return 0


train.__signature__ = inspect.signature(_train)  # type: ignore[attr-defined]
