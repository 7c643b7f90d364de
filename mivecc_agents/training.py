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

from mivecc_agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint
from mivecc_agents.networks import ACTION_SCALE_MPS2, make_actor, make_critic
from mivecc_agents.presets import DEFAULT_PRESET, TrainPreset, get_preset

__all__ = [
    "GROUPS",
    "STAGES",
    "TrainingError",
    "make_env",
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
    from torchrl.envs import Compose, PettingZooWrapper, RenameTransform, RewardSum, TransformedEnv

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
            RewardSum(
                in_keys=[(g, "reward") for g in groups],
                out_keys=[(g, "episode_reward") for g in groups],
            ),
        ),
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
) -> TensorDictSequential:
    """The collection policy: trained actor (+ noise) and the other group's fixed actions."""
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
    if stage == "edge":
        mods.append(zero_policy("cloud"))
    return TensorDictSequential(*mods)


def make_loss(actor: Any, critic: Any, group: str, gamma: float) -> Any:
    """DDPG loss of one agent group: target actor and critic, per-group keys, TD(0)."""
    from torchrl.objectives import DDPGLoss, ValueEstimators

    loss = DDPGLoss(actor, critic, delay_actor=True, delay_value=True)
    loss.set_keys(
        state_action_value=(group, "state_action_value"),
        reward=(group, "reward"),
        done=(group, "done"),
        terminated=(group, "terminated"),
        priority=(group, "td_error"),  # one priority key per group, not a shared root key
    )
    loss.make_value_estimator(ValueEstimators.TD0, gamma=gamma)
    return loss


def load_frozen_edge_actor(path: str | Path) -> TensorDictModule:
    """Load the stage-I edge actor, frozen (no grad, eval)."""
    ckpt = load_checkpoint(path, expected_kind="edge")
    actor = make_actor("edge", "edge")
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
    """Plot average travel velocity [m/s] vs frames, one line per density, from the CSV log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    csv_path = Path(csv_path)
    png_path = Path(png_path) if png_path else csv_path.with_suffix(".png")
    with csv_path.open() as fh:
        rows = list(csv.DictReader(fh))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    if rows:
        frames = [float(r["frames"]) for r in rows]
        ecols = [c for c in rows[0] if c.startswith("episode_velocity_mps_d")]
        plotted = False
        for c in ecols:  # final value of each finished episode
            pts = [(f, float(r[c])) for f, r in zip(frames, rows, strict=True) if r[c] != "nan"]
            if pts:
                xs, ys = zip(*pts, strict=True)
                axes[0].plot(xs, ys, "o-", label=f"{c[22:]} veh/lane/h")
                plotted = True
        if not plotted:  # no episode finished yet: running value of the current episode
            for c in (c for c in rows[0] if c.startswith("avg_velocity_mps_d")):
                axes[0].plot(frames, [float(r[c]) for r in rows], label=f"{c[18:]} veh/lane/h")
        axes[1].plot(frames, [float(r["critic_loss"]) for r in rows], label="critic loss")
        axes[1].plot(frames, [float(r["actor_loss"]) for r in rows], label="actor loss")
    axes[0].set_xlabel("environment frames [steps]")
    axes[0].set_ylabel("average travel velocity [m/s]")
    axes[0].set_title("average travel velocity at episode end")
    axes[0].legend(title="density")
    axes[1].set_xlabel("environment frames [steps]")
    axes[1].set_ylabel("loss [-]")
    axes[1].set_yscale("symlog")
    axes[1].legend()
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return png_path


def _flatten_ray_batch(data: TensorDictBase) -> TensorDictBase:
    """RayCollector stacks its workers' ``(n_densities, T)`` batches into ``(workers, n_dens,
    T)``: join the workers along time -> ``(n_densities, workers*T)``, the local layout."""
    return torch.cat(data.unbind(0), dim=1) if data.shape[0] > 1 else data[0]


def _make_collector(env_fn: Callable, policy, frames_per_batch, total_frames, workers, ray_address):
    from torchrl.collectors import Collector, MultiSyncCollector

    if ray_address is not None:
        try:
            import ray  # noqa: F401
        except ImportError as exc:
            raise TrainingError(
                "ray_address needs ray: install it with `pip install mivecc[ray]`"
            ) from exc
        from torchrl.collectors.distributed import RayCollector

        n = max(1, workers)
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
                [env_fn] * n,
                policy,
                frames_per_batch=frames_per_batch,
                total_frames=total_frames,
                ray_init_config=init,
                sync=True,
                postproc=_flatten_ray_batch,
            )
        except ConnectionError as exc:
            raise TrainingError(f"cannot connect to Ray at {ray_address!r}: {exc}") from exc
        collector.update_policy_weights_()  # connect the weight sync before the first batch
        return collector
    if workers > 1:
        return MultiSyncCollector(
            [env_fn] * workers,
            policy,
            frames_per_batch=frames_per_batch,
            total_frames=total_frames,
        )
    return Collector(
        env_fn,
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        auto_register_policy_transforms=False,
    )


def train(*args: Any, **kwargs: Any) -> Path:
    """Train one stage (see :func:`_train` for the arguments); returns the final checkpoint.

    TorchRL's exploration noise, replay sampling and network initialisation draw from torch's
    global generator, so training runs inside ``torch.random.fork_rng``: it is seeded with
    ``seed`` there and the caller's global random state is restored afterwards.
    """
    with torch.random.fork_rng(devices=[]):
        return _train(*args, **kwargs)


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
) -> Path:
    """Train one stage and return the path of the final checkpoint.

    Args:
        stage: ``"edge"`` (stage I, scheme EE) or ``"cloud"`` (stage II, scheme EEC).
        preset: Preset name or :class:`TrainPreset`.
        frames: Total env steps (summed over the density envs); default 50 episodes.
        rows, cols: Grid size.
        densities: One or several arrival densities [veh/lane/h], trained in parallel envs.
        seed: Seed of torch and the envs.
        out_dir: Output folder (``train_log.csv``, ``learning_curve.png``, ``<stage>.pt``).
        resume: Checkpoint of this stage to continue from (frames count continues).
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

    Returns:
        Path of the checkpoint written at the end.
    """
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
    from torchrl.modules import AdditiveGaussianModule
    from torchrl.objectives import SoftUpdate
    from tqdm.auto import tqdm

    if stage not in STAGES:
        raise TrainingError(f"unknown stage {stage!r}; expected 'edge' or 'cloud'")
    p = get_preset(preset)
    if buffer_size is not None:
        p = p.replace(buffer_size=int(buffer_size))
    if episode_steps is not None:
        p = p.replace(episode_steps=int(episode_steps))
    group = STAGES[stage]["group"]
    scheme = STAGES[stage]["scheme"]
    dens = (
        [float(densities)] if isinstance(densities, (int, float)) else [float(d) for d in densities]
    )
    if not dens:
        raise TrainingError("at least one density is needed")
    overrides = {
        **(config_overrides or {}),
        "rows": rows,
        "cols": cols,
        "max_steps": p.episode_steps,
    }
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    total_frames = int(frames) if frames is not None else 50 * p.episode_steps * len(dens)
    fpb = p.frames_per_batch * len(dens)
    torch.manual_seed(seed)

    # --- networks, loss, optimiser ------------------------------------------------------
    actor = make_actor(group, group)
    critic = make_critic(group, group)
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

    loss = make_loss(actor, critic, group, p.gamma)
    updater = SoftUpdate(loss, tau=p.tau)
    actor_params = list(actor.parameters())
    critic_params = list(critic.parameters())
    optim = torch.optim.Adam(
        [{"params": actor_params, "lr": p.lr_actor}, {"params": critic_params, "lr": p.lr_critic}]
    )
    state = {"frames": 0, "updates": 0, "iteration": 0}
    sched = torch.optim.lr_scheduler.LambdaLR(
        optim, lambda _: max(0.0, 1.0 - state["frames"] / max(total_frames, 1))
    )

    if resume is not None:
        ck = load_checkpoint(resume, expected_kind=group)
        if ck["stage"] != stage:
            raise CheckpointError(f"{resume}: is a {ck['stage']!r}-stage checkpoint, not {stage!r}")
        loss.load_state_dict(ck["loss"])
        optim.load_state_dict(ck["optimizer"])
        state.update(
            frames=int(ck["frames"]),
            updates=int(ck["updates"]),
            iteration=int(ck.get("metrics", {}).get("iteration", 0)),
        )
        sched.step()

    # --- exploration policy, env, collector ----------------------------------------------
    probe = make_env({**overrides, "density": dens[0]}, scheme)
    action_spec = probe.full_action_spec[(group, "action")]
    probe.close()
    noise = AdditiveGaussianModule(
        spec=action_spec,
        sigma_init=p.sigma_init,
        sigma_end=p.sigma_end,
        annealing_num_steps=max(1, int(p.sigma_anneal_fraction * total_frames)),
        action_key=(group, "action"),
    )
    if state["frames"]:
        noise.step(state["frames"])
    policy = make_policy(stage, actor, noise, frozen_edge)
    remaining = max(0, total_frames - state["frames"])
    env_fn = partial(_make_batched_env, dens, overrides, scheme)

    # --- replay buffer, sized on purpose ---------------------------------------------------
    keys = _buffer_keys(group)
    probe_td = env_fn()
    sample = probe_td.rollout(1, policy)
    probe_td.close()
    per_transition = sum(
        t.numel() * t.element_size() for t in sample.select(*keys).reshape(-1)[0].values(True, True)
    )
    cap_mem = int(p.buffer_memory_mb * 2**20 // max(per_transition, 1))
    capacity = max(p.batch_size, min(p.buffer_size, cap_mem))
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(capacity), batch_size=p.batch_size)

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
        "updates",
        "fps_collect",
        "fps_optim",
        "buffer",
        "wall_s",
    ]
    write_header = not (resume is not None and csv_path.exists())
    fh = csv_path.open("w" if write_header else "a", newline="")
    writer = csv.DictWriter(fh, fieldnames=fields)
    if write_header:
        writer.writeheader()
    tb = _tensorboard_writer(out_dir)

    ckpt_path = out_dir / f"{stage}.pt"
    meta = {
        "stage": stage,
        "kind": group,
        "grid_size": int(actor.module.spec.grid_size),
        "preset": p.to_dict(),
        "config": _config_dict(overrides, scheme, dens),
        "extra": {
            "edge_checkpoint": edge_ckpt_path,
            "densities": dens,
            "seed": seed,
            "buffer_capacity": capacity,
            "bytes_per_transition": per_transition,
        },
    }

    def _save(metrics: dict[str, float], path: Path = ckpt_path) -> Path:
        return save_checkpoint(
            path,
            {
                **meta,
                "actor": actor.module.state_dict(),
                "critic": critic.module.state_dict(),
                "loss": loss.state_dict(),
                "optimizer": optim.state_dict(),
                "frames": state["frames"],
                "updates": state["updates"],
                "metrics": {**metrics, "iteration": state["iteration"]},
            },
        )

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
    if remaining > 0:
        collector = _make_collector(env_fn, policy, fpb, remaining, workers, ray_address)
        collector.set_seed(seed + state["frames"])
        try:
            t_last = time.perf_counter()
            for data in collector:
                t_col = time.perf_counter() - t_last
                n = data.numel()
                state["frames"] += n
                state["iteration"] += 1
                buffer.extend(data.select(*keys).reshape(-1))
                noise.step(n)
                # --- optimisation
                t1 = time.perf_counter()
                n_upd = 0
                cl, al, qm = [], [], []
                if len(buffer) >= max(p.warmup_frames, p.batch_size):
                    n_upd = max(1, round(p.updates_per_frame * n))
                    for _ in range(n_upd):
                        batch = buffer.sample()
                        out = loss(batch)
                        total = out["loss_actor"] + out["loss_value"]
                        optim.zero_grad(set_to_none=True)
                        total.backward()
                        if p.max_grad_norm is not None:
                            nn.utils.clip_grad_norm_(actor_params, p.max_grad_norm)
                            nn.utils.clip_grad_norm_(critic_params, p.max_grad_norm)
                        optim.step()
                        updater.step()
                        cl.append(out["loss_value"].detach())
                        al.append(out["loss_actor"].detach())
                        qm.append(out["pred_value"].detach().mean())
                    state["updates"] += n_upd
                t_opt = time.perf_counter() - t1
                if n_upd:  # (stepping before the first optimizer.step() only warns)
                    sched.step()
                if workers > 1 or ray_address is not None:
                    collector.update_policy_weights_()
                metrics = _metrics(
                    data,
                    group=group,
                    densities=dens,
                    state=state,
                    episodes=episodes,
                    critic_losses=cl,
                    actor_losses=al,
                    q_means=qm,
                    optimizer=optim,
                    noise=noise,
                    frames_in_batch=n,
                    n_updates=n_upd,
                    collect_s=t_col,
                    optimise_s=t_opt,
                    buffer_len=len(buffer),
                    wall_s=time.perf_counter() - t0,
                    batch_size=p.batch_size,
                )
                episodes = int(metrics["episodes"])
                writer.writerow(metrics)
                fh.flush()
                if tb is not None:
                    for key, value in metrics.items():
                        if isinstance(value, int | float) and key not in ("iteration", "frames"):
                            tb.add_scalar(f"{stage}/{key}", value, int(metrics["frames"]))
                bar.update(n)
                bar.set_postfix(
                    v=f"{metrics['avg_velocity_mps']:.2f}", qloss=f"{metrics['critic_loss']:.3g}"
                )
                if save_every and state["iteration"] % save_every == 0:
                    _save(metrics)
                t_last = time.perf_counter()
        finally:
            collector.shutdown()
            bar.close()
            fh.close()
            if tb is not None:
                tb.close()
    else:
        bar.close()
        fh.close()
    path = _save(metrics)
    plot_learning_curve(csv_path, out_dir / "learning_curve.png")
    return path


def _tensorboard_writer(out_dir: Path) -> Any:
    """A TensorBoard ``SummaryWriter`` logging to ``out_dir/tb`` if tensorboard is installed."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is optional: the CSV log is always written
        return None
    return SummaryWriter(log_dir=str(out_dir / "tb"))


def _config_dict(overrides: dict[str, Any], scheme: str, dens: list[float]) -> dict[str, Any]:
    from mivecc_env.config import from_overrides

    return from_overrides(None, **{**overrides, "scheme": scheme, "density": dens[0]}).to_dict()


def _mean(xs: list[torch.Tensor]) -> float:
    return float(torch.stack(xs).mean()) if xs else math.nan


def _metrics(
    data: TensorDictBase,
    *,
    group: str,
    densities: list[float],
    state: dict[str, int],
    episodes: int,
    critic_losses: list[torch.Tensor],
    actor_losses: list[torch.Tensor],
    q_means: list[torch.Tensor],
    optimizer: torch.optim.Optimizer,
    noise: Any,
    frames_in_batch: int,
    n_updates: int,
    collect_s: float,
    optimise_s: float,
    buffer_len: int,
    wall_s: float,
    batch_size: int,
) -> dict[str, float]:
    """One CSV row. ``data`` has batch dims ``(n_densities, T)`` (or flattened by workers)."""
    nxt = data["next"]
    reward = nxt[group, "reward"]
    done = nxt["done"].reshape(-1)
    # The episode summary is in the cloud agent's info (the whole network), shape (..., 1).
    vel = nxt["cloud", "info", "avg_travel_velocity_mps"]
    vel = torch.where(nxt["cloud", "info", "throughput"] > 0, vel, math.nan)  # NaN: none exited
    coll = nxt["cloud", "info", "collisions"]
    row: dict[str, float] = {
        "iteration": state["iteration"],
        "frames": state["frames"],
        "episodes": episodes + int(done.sum()),
        "reward_mean": float(reward.mean()),
        "episode_reward": math.nan,
        "collisions": float(coll.reshape(-1, coll.shape[-1])[:, 0].max()),
        "critic_loss": _mean(critic_losses),
        "actor_loss": _mean(actor_losses),
        "q_mean": _mean(q_means),
        "lr_actor": optimizer.param_groups[0]["lr"],
        "lr_critic": optimizer.param_groups[1]["lr"],
        "sigma": float(noise.sigma),
        "updates": n_updates,
        "fps_collect": frames_in_batch / max(collect_s, 1e-9),
        "fps_optim": n_updates * batch_size / max(optimise_s, 1e-9) if n_updates else math.nan,
        "buffer": buffer_len,
        "wall_s": wall_s,
    }
    # per density: the running episode value at the last step of the batch, and the final
    # value of the last episode that ended in this batch (NaN if none ended)
    if vel.ndim >= 3 and vel.shape[0] == len(densities):
        per_d = vel[..., 0]  # (n_densities, T)
        done_d = nxt["done"].reshape(per_d.shape)
    else:
        per_d = vel.reshape(-1, vel.shape[-1])[:, 0].unsqueeze(0).expand(len(densities), -1)
        done_d = done.unsqueeze(0).expand(len(densities), -1)
    for i, d in enumerate(densities):
        row[f"avg_velocity_mps_d{_fmt_density(d)}"] = float(per_d[i, -1])
        ends = torch.nonzero(done_d[i]).flatten()
        row[f"episode_velocity_mps_d{_fmt_density(d)}"] = (
            float(per_d[i, ends[-1]]) if ends.numel() else math.nan
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
    import sys

    from mivecc_agents.cli import parse_set_items

    if args.threads:
        torch.set_num_threads(args.threads)
    default = 1 if args.stage == "edge" else 3
    try:
        path = train(
            args.stage, args.preset, args.frames,
            rows=args.rows or default, cols=args.cols or default, densities=args.density,
            seed=args.seed, out_dir=args.out, resume=args.resume, workers=args.workers,
            ray_address=args.ray_address, progress=not args.no_progress,
            edge_checkpoint=args.edge_checkpoint, config_overrides=parse_set_items(args.set_items),
            episode_steps=args.episode_steps, buffer_size=args.buffer_size,
        )
    except (TrainingError, CheckpointError) as exc:
        print(f"mivecc train: error: {exc}", file=sys.stderr)
        return 2
    print(path)
    return 0


train.__signature__ = inspect.signature(_train)  # type: ignore[attr-defined]
