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
"""

from __future__ import annotations

import contextlib
import csv
import inspect
import math
import time
from collections.abc import Callable, Sequence
from functools import partial
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
from mivecc_agents.exploration import make_exploration
from mivecc_agents.learner import (
    SATURATED_Z,
    DDPGLearner,
    UpdateStats,
    make_loss,
    saturated_share,
)
from mivecc_agents.macro_steps import cloud_macro_transitions
from mivecc_agents.networks import (
    ACTION_SCALE_MPS2,
    critic_members_in,
    make_actor,
    make_critic,
)
from mivecc_agents.presets import DEFAULT_PRESET, TrainPreset, get_preset
from mivecc_agents.reward_shaping import potential_keys, shape_rewards

__all__ = [
    "GROUPS",
    "STAGES",
    "TrainingError",
    "TrainingInterrupted",
    "env_factory",
    "make_env",
    "make_loss",
    "make_native_env",
    "make_policy",
    "plot_learning_curve",
    "train",
]

GROUPS = ("edge", "cloud")
STAGES: dict[str, dict[str, str]] = {
    "edge": {"scheme": "EE", "group": "edge"},
    "cloud": {"scheme": "EEC", "group": "cloud"},
}


class TrainingError(RuntimeError):
    """Training cannot start (bad arguments, missing stage-I checkpoint, missing ray...)."""


# --------------------------------------------------------------------------------------------
# Environment
def make_env(config_overrides: dict[str, Any] | None = None, scheme: str | None = None):
    """Build the TorchRL env: PettingZoo wrapper + ``(g, "mask")`` at root and under ``next``.

    Args:
        config_overrides: MiVeCC config fields (``rows``, ``cols``, ``density``, ...).
        scheme: ``"E"``, ``"EE"`` or ``"EEC"`` (overrides the config's).

    Returns:
        A ``TransformedEnv`` with groups ``edge`` and ``cloud``.
    """
    from torchrl.envs import Compose, PettingZooWrapper, RenameTransform, TransformedEnv

    from mivecc_env import mivecc_v0

    overrides = dict(config_overrides or {})
    if scheme is not None:
        overrides["scheme"] = scheme
    base = PettingZooWrapper(
        mivecc_v0.parallel_env(**overrides),
        use_mask=False,
        categorical_actions=False,
        return_state=False,
    )
    groups = [g for g in GROUPS if g in base.group_map]
    return TransformedEnv(
        base,
        Compose(
            RenameTransform(
                in_keys=[(g, "info", "mask") for g in groups],
                out_keys=[(g, "mask") for g in groups],
                create_copy=True,
            ),
            _episode_reward_sum(base),
        ),
    )


def _episode_reward_sum(base: Any) -> Any:
    """``RewardSum`` of each agent group's reward into ``(g, "episode_reward")``."""
    from torchrl.envs import RewardSum

    groups = [g for g in GROUPS if g in base.group_map]
    return RewardSum(
        in_keys=[(g, "reward") for g in groups],
        out_keys=[(g, "episode_reward") for g in groups],
    )


def _make_batched_env(densities: Sequence[float], overrides: dict[str, Any], scheme: str):
    """One env per density in a SerialEnv (batch dim 0 indexes the density)."""
    from torchrl.envs import SerialEnv

    fns = [partial(make_env, {**overrides, "density": float(d)}, scheme) for d in densities]
    return SerialEnv(len(fns), fns)


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


def _fmt_density(d: float) -> str:
    return f"{d:g}"


def plot_learning_curve(csv_path: str | Path, png_path: str | Path | None = None) -> Path:
    """Plot average travel velocity [m/s] vs frames per density from the CSV log: the running
    value of the current episode (thin) and the value at each episode's end (dots); the
    losses; and, where the log has it, the share of the actor's saturated outputs [%]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    csv_path = Path(csv_path)
    png_path = Path(png_path) if png_path else csv_path.with_suffix(".png")
    with csv_path.open() as fh:
        rows = list(csv.DictReader(fh))
    saturation = bool(rows) and "actor_saturated" in rows[0]  # not in older runs' logs
    fig, axes = plt.subplots(1, 3 if saturation else 2, figsize=(16 if saturation else 11, 4))
    if rows:
        frames = [float(r["frames"]) for r in rows]
        ecols = [c for c in rows[0] if c.startswith("episode_velocity_mps_d")]
        for c in ecols:
            d = c[22:]
            # running value of the current episode (thin), final value of each episode (dots)
            line, = axes[0].plot(frames, [float(r[f"avg_velocity_mps_d{d}"]) for r in rows],
                                 lw=0.8, alpha=0.5, label=f"{d} veh/lane/h, running")
            pts = [(f, float(r[c])) for f, r in zip(frames, rows, strict=True) if r[c] != "nan"]
            if pts:
                xs, ys = zip(*pts, strict=True)
                axes[0].plot(xs, ys, "o-", color=line.get_color(),
                             label=f"{d} veh/lane/h, episode end")
        axes[1].plot(frames, [float(r["critic_loss"]) for r in rows], label="critic loss")
        axes[1].plot(frames, [float(r["actor_loss"]) for r in rows], label="actor loss")
    axes[0].set_xlabel("environment frames [steps]")
    axes[0].set_ylabel("average travel velocity [m/s]")
    axes[0].set_title("average travel velocity of the episode (chunk)")
    axes[0].legend(title="density")
    axes[1].set_xlabel("environment frames [steps]")
    axes[1].set_ylabel("loss [-]")
    axes[1].set_yscale("symlog")
    axes[1].legend()
    if saturation:
        share = [100 * float(r["actor_saturated"] or "nan") for r in rows]
        axes[2].plot([float(r["frames"]) for r in rows], share, "o-", lw=1.0, ms=2)
        axes[2].set_xlabel("environment frames [steps]")
        axes[2].set_ylabel(f"actor outputs with |z| > {SATURATED_Z:g} [%]")
        axes[2].set_ylim(-2, 102)
        axes[2].set_title("saturated actor outputs (real columns)")
    thousands = FuncFormatter(lambda x, _: f"{x / 1000:g}k" if x else "0")
    for ax in axes:  # "150k", not "150000": full numbers overlap on three panels
        ax.xaxis.set_major_formatter(thousands)
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return png_path


def _flatten_ray_batch(data: TensorDictBase) -> TensorDictBase:
    """RayCollector stacks its workers' ``(n_densities, T)`` batches into ``(workers, n_dens,
    T)``: join the workers along time -> ``(n_densities, workers*T)``, the local layout."""
    return torch.cat(data.unbind(0), dim=1) if data.shape[0] > 1 else data[0]


def _make_collector(
    env_fn: Callable | Sequence[Callable],
    policy,
    frames_per_batch,
    total_frames,
    workers,
    ray_address,
):
    """Collector over ``env_fn`` (or one factory per worker): local, multi-process or Ray.

    The local collector yields its own rollout buffer (``return_same_td=True``), overwritten
    by the next batch: the training loop copies what it keeps (into the replay buffer) before
    asking for the next one. Without it TorchRL clones every batch, a fresh copy of all its
    observations (about 650 MB per stage-II batch of 48 x 100 frames).

    ``frames_per_batch`` is what all workers together collect per iteration; the training loop
    makes it whole steps of every worker's environments, so each worker's share is exact and
    ``total_frames`` is rounded up to whole batches (what TorchRL would collect anyway).
    """
    from torchrl.collectors import Collector, MultiSyncCollector

    # Every collector keeps the env as given: TorchRL would otherwise warn (and, from 0.15,
    # add an InitTracker transform) for the policy, in the driver or in each worker.
    keep_env = {"auto_register_policy_transforms": False}
    if total_frames > 0:  # whole batches, as collected anyway (TorchRL warns otherwise)
        total_frames = -(-total_frames // frames_per_batch) * frames_per_batch
    n = max(1, workers)
    fns = list(env_fn) if isinstance(env_fn, Sequence) else [env_fn] * n
    if len(fns) != n:
        raise TrainingError(f"{len(fns)} env factories for {n} workers")
    if ray_address is not None:
        try:
            import ray  # noqa: F401
        except ImportError as exc:
            raise TrainingError(
                "ray_address needs ray: install it with `pip install mivecc[ray]`"
            ) from exc
        from torchrl.collectors.distributed import RayCollector

        from mivecc_agents.ray_worker import RayWorkerCollector

        if frames_per_batch % n:
            raise TrainingError(
                f"ray: {frames_per_batch} frames per batch cannot be split over {n} workers"
            )
        # "local": start a fresh single-node Ray instance with enough CPUs for the workers
        # (each remote collector asks for 1 CPU); "auto" / "host:port" / "ray://..." go to
        # ray.init(address=...). If ray is already initialised, RayCollector uses that runtime.
        init: dict[str, Any] = {"address": ray_address}
        if ray_address == "local":
            import os

            init.update(num_cpus=max(n, os.cpu_count() or 1), include_dashboard=False)
        try:
            collector = RayCollector(
                fns,
                policy,
                frames_per_batch=frames_per_batch,
                total_frames=total_frames,
                ray_init_config=init,
                sync=True,
                postproc=_flatten_ray_batch,
                collector_class=RayWorkerCollector,
                collector_kwargs=dict(keep_env),
            )
        except ConnectionError as exc:
            raise TrainingError(f"cannot connect to Ray at {ray_address!r}: {exc}") from exc
        collector.update_policy_weights_()  # connect the weight sync before the first batch
        return collector
    if n > 1:
        return MultiSyncCollector(
            fns,
            policy,
            frames_per_batch=frames_per_batch,
            total_frames=total_frames,
            **keep_env,
        )
    return Collector(
        fns[0],
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        return_same_td=True,
        **keep_env,
    )


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


def _densities(densities: float | Sequence[float]) -> list[float]:
    if isinstance(densities, (int, float)):
        return [float(densities)]
    dens = [float(d) for d in densities]
    if not dens:
        raise TrainingError("at least one density is needed")
    return dens


def env_factory(
    backend: str,
    densities: Sequence[float],
    overrides: dict[str, Any],
    scheme: str,
    envs_per_density: int = 1,
    seed: int | None = None,
    env_options: dict[str, Any] | None = None,
) -> tuple[Callable[[], Any], list[int]]:
    """The collector's env factory and the density index of each of its environments.

    Args:
        backend: ``"native"`` (:class:`~mivecc_agents.torchrl_env.MiVeCCTorchEnv`, one
            simulator for ``envs_per_density x len(densities)`` environments) or
            ``"pettingzoo"`` (``PettingZooWrapper`` envs in a ``SerialEnv``, one per density).
        densities: Training densities [veh/lane/h].
        overrides: Env config fields (grid, episode length...).
        scheme: ``"EE"`` or ``"EEC"``.
        envs_per_density: Environments per density (native backend).
        seed: Native backend: seed of the env (environment ``b`` gets ``seed + b``).
        env_options: Native backend: ``continuous`` / ``raw_edge_period`` of
            :class:`~mivecc_agents.torchrl_env.MiVeCCTorchEnv` (the pettingzoo backend has
            neither: asking for them there is a ``TrainingError``).

    Returns:
        ``(factory, env_density)`` with ``env_density[b]`` the index into ``densities`` of
        environment ``b`` (batch dim 0 of the collected data).
    """
    options = {k: v for k, v in (env_options or {}).items() if v}
    if backend == "pettingzoo":
        if options:
            raise TrainingError(
                f"backend 'pettingzoo' has no {sorted(options)}: use the native backend"
            )
        return partial(_make_batched_env, list(densities), overrides, scheme), list(
            range(len(densities))
        )
    if backend != "native":
        raise TrainingError(f"backend: must be 'native' or 'pettingzoo', got {backend!r}")
    if envs_per_density < 1:
        raise TrainingError(f"envs_per_density: must be >= 1, got {envs_per_density}")
    env_density = [i for i in range(len(densities)) for _ in range(envs_per_density)]
    per_env = [float(densities[i]) for i in env_density]
    return partial(make_native_env, per_env, overrides, scheme, seed, **options), env_density


#: Groups the native env exposes in each stage (stage I needs no cloud graph).
_STAGE_GROUPS = {"EE": ("edge",), "EEC": ("edge", "cloud")}
#: Episode-summary keys the training log reads.
_LOG_KEYS = ("avg_travel_velocity_mps", "collisions", "throughput")


def make_native_env(
    densities: Sequence[float],
    overrides: dict[str, Any],
    scheme: str,
    seed: int | None = None,
    **options: Any,
):
    """Native batched TorchRL env (one environment per entry of ``densities``) + RewardSum.

    It has the keys of :func:`make_env` that training reads: ``(g, "mask")`` at the root and
    under ``next``, and the ``(g, "info")`` summary keys of the log. Scheme ``EE`` exposes only
    the ``edge`` group (stage I acts on no cloud graph, so none is built). ``options``:
    ``continuous``, ``raw_edge_period`` of the env.
    """
    from torchrl.envs import TransformedEnv

    from mivecc_agents.torchrl_env import MiVeCCTorchEnv

    base = MiVeCCTorchEnv(
        densities=list(densities),
        scheme=scheme,
        groups=_STAGE_GROUPS.get(scheme, GROUPS),
        summary_keys=_LOG_KEYS,
        seed=seed,
        **options,
        **overrides,
    )
    return TransformedEnv(base, _episode_reward_sum(base))


def env_groups(env: Any) -> list[str]:
    """The agent groups (``edge``, ``cloud``) that an env (or a batch of envs) has."""
    acts = env.full_action_spec.keys()
    return [g for g in GROUPS if g in acts]


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
        save_every: Save a checkpoint every this many iterations.
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
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
    from tqdm.auto import tqdm

    if stage not in STAGES:
        raise TrainingError(f"unknown stage {stage!r}; expected 'edge' or 'cloud'")
    device = learner_device(device)
    p = get_preset(preset).for_stage(stage)
    if buffer_size is not None:
        p = p.replace(buffer_size=int(buffer_size))
    if episode_steps is not None:
        p = p.replace(episode_steps=int(episode_steps))
    if envs_per_density is not None:
        p = p.replace(envs_per_density=int(envs_per_density))
    group = STAGES[stage]["group"]
    scheme = STAGES[stage]["scheme"]
    dens = _densities(densities)
    overrides = {
        **dict(p.env_overrides),
        **(config_overrides or {}),
        "rows": rows,
        "cols": cols,
        "max_steps": p.episode_steps,
    }
    if p.envs_per_density is None:
        p = p.replace(envs_per_density=max(1, p.envs // len(dens)))
    env_options = _env_options(p)
    env_fn, env_density = env_factory(
        backend, dens, overrides, scheme, p.envs_per_density, seed, env_options
    )
    n_envs = len(env_density)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    total_frames = int(frames) if frames is not None else 50 * p.episode_steps * len(dens)
    torch.manual_seed(seed)

    # --- networks, learner ------------------------------------------------------------------
    start = _load_start(resume, stage, group) if resume is not None else None
    if start is not None and network_variant(start) != p.network:
        import sys

        print(f"mivecc train: {resume} holds {network_variant(start)!r} networks: continuing "
              f"with those (the preset names {p.network!r})", file=sys.stderr)
        p = p.replace(network=network_variant(start))
    held = critic_members_in(start["critic"]) if start is not None else p.critic_members
    if held != p.critic_members:
        import sys

        print(f"mivecc train: {resume} holds {held} critic(s): continuing with those (the "
              f"preset names {p.critic_members})", file=sys.stderr)
        p = p.replace(critic_members=held)
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
    frozen_edge = None
    edge_ckpt_path = None
    if stage == "cloud":
        if edge_checkpoint is None:
            from mivecc_agents.policies import pretrained_path

            edge_checkpoint = pretrained_path("edge")
            if edge_checkpoint is None:
                raise TrainingError(
                    "stage 'cloud' needs a stage-I edge checkpoint (edge_checkpoint=...)"
                )
        edge_ckpt_path = str(edge_checkpoint)
        frozen_edge = load_frozen_edge_actor(edge_checkpoint)

    state = {"frames": 0, "updates": 0, "iteration": 0}
    # the learner's networks on ``device``; ``actor`` keeps acting in the envs on the CPU
    learn_actor, learn_critic, sync_actor = _learner_networks(actor, critic, device)
    twin = (make_critic(group, group, variant=p.network).to(device)
            if p.algorithm == "td3" else None)  # TD3's second critic, its own initialisation
    learner = DDPGLearner(
        learn_actor, learn_critic, group, p,
        progress=lambda: state["frames"] / max(total_frames, 1), twin=twin,
    )
    if start is not None and not warm:
        learner.load_state_dict(start)
        sync_actor()
        state.update(
            frames=int(start["frames"]),
            updates=int(start["updates"]),
            iteration=int(start.get("metrics", {}).get("iteration", 0)),
        )
        learner.updates = state["updates"]

    # --- exploration policy, env, collector ----------------------------------------------
    probe = env_fn()
    action_spec = probe.full_action_spec[(group, "action")].clone()
    noise = make_exploration(
        p.exploration,
        action_spec,
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
    # steps of each env per iteration: the preset's, fewer if the run is shorter than that;
    # several collector workers (each with its own n_envs environments) share them
    n_workers = max(1, workers)
    steps = -(-max(1, min(p.frames_per_batch, -(-remaining // n_envs))) // n_workers)
    cloud_period = _cloud_period(stage, overrides, dens[0])
    if cloud_period > 1:  # whole decision blocks per batch (cloud_macro_transitions)
        steps = cloud_period * max(1, steps // cloud_period)
    fpb = n_workers * n_envs * steps  # what the collector(s) really collect per iteration

    # --- replay buffer, sized on purpose ---------------------------------------------------
    keys = _buffer_keys(group)
    shaping = p.reward_shaping == "potential"
    collect_keys = keys + potential_keys(group) if shaping else keys
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

    csv_path = out_dir / "train_log.csv"
    fields = [
        "iteration",
        "frames",
        "episodes",
        "reward_mean",
        "episode_reward",
        "avg_velocity_mps",
        *[f"avg_velocity_mps_d{_fmt_density(d)}" for d in dens],
        *[f"episode_velocity_mps_d{_fmt_density(d)}" for d in dens],
        "collisions",
        "critic_loss",
        "actor_loss",
        "q_mean",
        "lr_actor",
        "lr_critic",
        "sigma",
        "actor_saturated",
        "updates",
        "fps_collect",
        "fps_optim",
        "buffer",
        "wall_s",
    ]
    append_logs = resume is not None and not warm and csv_path.exists()  # continuing a run
    fh, writer = open_log(csv_path, fields, append=append_logs)
    tb = _tensorboard_writer(out_dir)

    ckpt_path = out_dir / f"{stage}.pt"
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

    def _save(metrics: dict[str, Any], path: Path = ckpt_path, slim: bool = False) -> Path:
        """The run's checkpoint; ``slim``: without the optimiser and target copies (it loads
        with ``load_policy`` but cannot be resumed)."""
        return save_checkpoint(
            path,
            {
                **meta,
                "actor": actor.module.state_dict(),
                "critic": _on_cpu(learner.critic_state_dict()),
                **({} if slim else _on_cpu(learner.state_dict())),
                "frames": state["frames"],
                "updates": state["updates"],
                "metrics": {**metrics, "iteration": state["iteration"]},
            },
        )

    evaluate = _periodic_evaluation(p, stage, rows, cols, dens, config_overrides or {},
                                    out_dir, edge_ckpt_path, append=append_logs)
    next_eval, last_eval = state["frames"], None
    best_path = out_dir / f"{stage}_best.pt"  # the policy of the best evaluation so far
    best_score = _best_score(best_path, p.eval_select) if append_logs else -math.inf

    def _maybe_evaluate(final: bool = False) -> None:
        """Evaluate when due; ``final``: unless the current weights were just evaluated."""
        nonlocal next_eval, last_eval, best_score
        due = state["frames"] != last_eval if final else state["frames"] >= next_eval
        if evaluate is None or not due:
            return
        last_eval = state["frames"]
        scores = evaluate(actor.module, state["frames"], state["updates"])
        score = scores.score(p.eval_select)
        if score > best_score:  # NaN (no baseline velocity) never counts as better
            best_score = score
            _save({"eval_gain_pct": scores.mean_gain_pct,
                   "eval_min_ceiling_share_pct": scores.min_ceiling_share_pct,
                   "eval_select": p.eval_select, "eval_score": score}, best_path, slim=True)
        if progress:
            import sys

            bar.write(f"eval at {state['frames']} frames: {evaluate.scheme} gain "
                      f"{scores.mean_gain_pct:+.2f} %, at least "
                      f"{scores.min_ceiling_share_pct:.0f} % of the +3 ceiling's", file=sys.stderr)
        next_eval = state["frames"] + p.eval_every_frames

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
            _maybe_evaluate()
            if remaining > 0 and not stop.requested:
                collector = _make_collector(
                    _worker_env_fns(backend, dens, overrides, scheme, p, seed, state, workers,
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
                    if cloud_period > 1:
                        batch = cloud_macro_transitions(data, cloud_period, collect_keys)
                    else:
                        batch = data.select(*collect_keys)
                    if shaping:  # sets a new reward tensor: the logs below keep the raw one
                        batch = shape_rewards(batch, group, p.gamma)
                    buffer.extend(batch.select(*keys).reshape(-1))
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
                    metrics = _metrics(
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
                    _log_tensorboard(tb, stage, metrics)
                    bar.update(n)
                    bar.set_postfix(
                        v=f"{metrics['avg_velocity_mps']:.2f}",
                        qloss=f"{metrics['critic_loss']:.3g}",
                    )
                    if stop.requested:
                        break
                    if save_every and state["iteration"] % save_every == 0:
                        _save(metrics)
                    _maybe_evaluate()
                    t_last = time.perf_counter()
            if not stop.requested:
                _maybe_evaluate(final=True)
        finally:
            if collector is not None:
                with contextlib.suppress(Exception):  # an interrupted worker may be gone
                    collector.shutdown()
            bar.close()
            fh.close()
            if tb is not None:
                tb.close()
        path = _save(metrics)
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


def _tensorboard_writer(out_dir: Path) -> Any:
    """A TensorBoard ``SummaryWriter`` logging to ``out_dir/tb`` if tensorboard is installed."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is optional: the CSV log is always written
        return None
    return SummaryWriter(log_dir=str(out_dir / "tb"))


def _worker_env_fns(
    backend: str,
    dens: list[float],
    overrides: dict[str, Any],
    scheme: str,
    p: TrainPreset,
    seed: int,
    state: dict[str, int],
    workers: int,
    env_options: dict[str, Any] | None = None,
) -> list[Callable]:
    """One env factory per collector worker; native envs get distinct seeds per worker (and
    per resumed run: the frame count is added)."""
    n = max(1, workers)
    n_envs = p.envs_per_density * len(dens)
    base = seed + state["frames"]
    return [
        env_factory(backend, dens, overrides, scheme, p.envs_per_density, base + w * n_envs,
                    env_options)[0]
        for w in range(n)
    ]


def _log_tensorboard(tb: Any, stage: str, metrics: dict[str, float]) -> None:
    """Every numeric metric as a TensorBoard scalar at the current frame count."""
    if tb is None:
        return
    for key, value in metrics.items():
        if isinstance(value, int | float) and key not in ("iteration", "frames"):
            tb.add_scalar(f"{stage}/{key}", value, int(metrics["frames"]))


def _config_dict(overrides: dict[str, Any], scheme: str, dens: list[float]) -> dict[str, Any]:
    from mivecc_env.config import from_overrides

    return from_overrides(None, **{**overrides, "scheme": scheme, "density": dens[0]}).to_dict()


def _summary_entry(nxt: TensorDictBase, group: str, key: str) -> torch.Tensor:
    """An episode-summary entry ``(..., n_agents)``: from the group's infos, else from the
    cloud agent's (the PettingZoo env puts the summary there only), else NaN."""
    for g in (group, "cloud"):
        value = nxt.get((g, "info", key), None)
        if value is not None:
            return value
    shape = nxt[group, "reward"].shape[:-1]
    return torch.full(shape, math.nan)


def open_log(path: Path, fields: Sequence[str], append: bool) -> tuple[Any, csv.DictWriter]:
    """Open a CSV log for writing rows of ``fields``: a new file with its header, or (with
    ``append`` and an existing file) the file to continue. A file written with other columns
    (an earlier version's run being resumed) is first rewritten with ``fields`` as its header,
    its rows kept (blank where they lack a column; columns no longer written are dropped)."""
    if append and path.exists():
        with path.open(newline="") as fh:
            reader = csv.DictReader(fh)
            old_fields, rows = reader.fieldnames or [], list(reader)
        if list(old_fields) != list(fields):
            with path.open("w", newline="") as fh:
                rewrite = csv.DictWriter(fh, fieldnames=list(fields), restval="",
                                         extrasaction="ignore")
                rewrite.writeheader()
                rewrite.writerows(rows)
        fh = path.open("a", newline="")
        return fh, csv.DictWriter(fh, fieldnames=list(fields))
    fh = path.open("w", newline="")
    writer = csv.DictWriter(fh, fieldnames=list(fields))
    writer.writeheader()
    fh.flush()
    return fh, writer


def _metrics(
    data: TensorDictBase,
    *,
    group: str,
    densities: list[float],
    env_density: list[int],
    state: dict[str, int],
    episodes: int,
    stats: UpdateStats,
    lr: tuple[float, float],
    noise: Any,
    frames_in_batch: int,
    collect_s: float,
    buffer_len: int,
    wall_s: float,
    batch_size: int,
) -> dict[str, float]:
    """One CSV row. ``data`` has batch dims ``(n_envs, T)`` (or flattened by workers);
    ``env_density[b]`` is the density index of environment ``b``."""
    nxt = data["next"]
    reward = nxt[group, "reward"]
    done = nxt["done"].reshape(-1)
    vel = _summary_entry(nxt, group, "avg_travel_velocity_mps")  # (..., n_agents)
    vel = torch.where(_summary_entry(nxt, group, "throughput") > 0, vel, math.nan)  # none exited
    coll = _summary_entry(nxt, group, "collisions")
    row: dict[str, float] = {
        "iteration": state["iteration"],
        "frames": state["frames"],
        "episodes": episodes + int(done.sum()),
        "reward_mean": float(reward.mean()),
        "episode_reward": math.nan,
        "collisions": float(coll.reshape(-1, coll.shape[-1])[:, 0].max()),
        "critic_loss": stats.critic_loss,
        "actor_loss": stats.actor_loss,
        "q_mean": stats.q_mean,
        "lr_actor": lr[0],
        "lr_critic": lr[1],
        "sigma": float(noise.sigma) if noise is not None else 0.0,
        "updates": stats.n_updates,
        "fps_collect": frames_in_batch / max(collect_s, 1e-9),
        "fps_optim": (
            stats.n_updates * batch_size / max(stats.seconds, 1e-9) if stats.n_updates else math.nan
        ),
        "buffer": buffer_len,
        "wall_s": wall_s,
    }
    # per density: the running episode value at the last step of the batch (mean over the
    # density's environments), and the final value of the episodes that ended in this batch
    # (NaN if none ended)
    n_envs = len(env_density)
    if vel.ndim >= 3 and vel.shape[0] == n_envs:
        per_env = vel[..., 0]  # (n_envs, T)
        done_e = nxt["done"].reshape(per_env.shape)
        owner = torch.as_tensor(env_density)
        for i, d in enumerate(densities):
            sel = owner == i
            row[f"avg_velocity_mps_d{_fmt_density(d)}"] = float(per_env[sel, -1].nanmean())
            ended = per_env[sel][done_e[sel]]
            row[f"episode_velocity_mps_d{_fmt_density(d)}"] = (
                float(ended.nanmean()) if ended.numel() else math.nan
            )
    else:  # layout unknown (e.g. flattened by collector workers): one value for all densities
        flat = vel.reshape(-1, vel.shape[-1])[:, 0]
        ended = flat[done]
        for d in densities:
            row[f"avg_velocity_mps_d{_fmt_density(d)}"] = float(flat[-1])
            row[f"episode_velocity_mps_d{_fmt_density(d)}"] = (
                float(ended.nanmean()) if ended.numel() else math.nan
            )
    per_density = [row[f"avg_velocity_mps_d{_fmt_density(d)}"] for d in densities]
    row["avg_velocity_mps"] = sum(per_density) / len(densities)
    if done.any():
        ep = nxt[group, "episode_reward"]  # (..., n_agents, 1), summed by RewardSum
        ep = ep.reshape(done.shape[0], -1)[done]
        row["episode_reward"] = float(ep.mean())
    return row


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
