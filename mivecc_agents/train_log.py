"""The training run's log: one CSV row per iteration, TensorBoard scalars, and the
learning-curve figure."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase

from mivecc_agents.learner import SATURATED_Z, UpdateStats

__all__ = ["fmt_density", "log_fields", "log_row", "log_tensorboard", "open_log",
           "plot_learning_curve", "tensorboard_writer"]


def fmt_density(d: float) -> str:
    return f"{d:g}"


def log_fields(densities: Sequence[float]) -> list[str]:
    """The columns of ``train_log.csv`` (per-density velocities for each training density)."""
    return [
        "iteration",
        "frames",
        "episodes",
        "reward_mean",
        "episode_reward",
        "avg_velocity_mps",
        *[f"avg_velocity_mps_d{fmt_density(d)}" for d in densities],
        *[f"episode_velocity_mps_d{fmt_density(d)}" for d in densities],
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


def tensorboard_writer(out_dir: Path) -> Any:
    """A TensorBoard ``SummaryWriter`` logging to ``out_dir/tb`` if tensorboard is installed."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is optional: the CSV log is always written
        return None
    return SummaryWriter(log_dir=str(out_dir / "tb"))


def log_tensorboard(tb: Any, stage: str, metrics: dict[str, float]) -> None:
    """Every numeric metric as a TensorBoard scalar at the current frame count."""
    if tb is None:
        return
    for key, value in metrics.items():
        if isinstance(value, int | float) and key not in ("iteration", "frames"):
            tb.add_scalar(f"{stage}/{key}", value, int(metrics["frames"]))


def summary_entry(nxt: TensorDictBase, group: str, key: str) -> torch.Tensor:
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


def log_row(
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
    vel = summary_entry(nxt, group, "avg_travel_velocity_mps")  # (..., n_agents)
    vel = torch.where(summary_entry(nxt, group, "throughput") > 0, vel, math.nan)  # none exited
    coll = summary_entry(nxt, group, "collisions")
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
            row[f"avg_velocity_mps_d{fmt_density(d)}"] = float(per_env[sel, -1].nanmean())
            ended = per_env[sel][done_e[sel]]
            row[f"episode_velocity_mps_d{fmt_density(d)}"] = (
                float(ended.nanmean()) if ended.numel() else math.nan
            )
    else:  # layout unknown (e.g. flattened by collector workers): one value for all densities
        flat = vel.reshape(-1, vel.shape[-1])[:, 0]
        ended = flat[done]
        for d in densities:
            row[f"avg_velocity_mps_d{fmt_density(d)}"] = float(flat[-1])
            row[f"episode_velocity_mps_d{fmt_density(d)}"] = (
                float(ended.nanmean()) if ended.numel() else math.nan
            )
    per_density = [row[f"avg_velocity_mps_d{fmt_density(d)}"] for d in densities]
    row["avg_velocity_mps"] = sum(per_density) / len(densities)
    if done.any():
        ep = nxt[group, "episode_reward"]  # (..., n_agents, 1), summed by RewardSum
        ep = ep.reshape(done.shape[0], -1)[done]
        row["episode_reward"] = float(ep.mean())
    return row
