"""Training throughput: collection frames/s, learner updates/s, end-to-end frames/s, old vs new.

Both paths run in the same process, interleaved (round-robin over ``--repeats``), so their ratio
is meaningful on a shared machine:

* ``old``: ``PettingZooWrapper`` envs in a ``SerialEnv`` (one env per density), the paper's
  minibatch 48 at 0.5 updates per frame (the training defaults before the native env);
* ``new``: the native batched TorchRL env (``MiVeCCTorchEnv``, ``--envs-per-density``
  environments per density in one simulator; default 16 x 3 densities and 48 x 1, what the
  default preset's 48 environments give) and the default preset (minibatch 192 at 0.125
  updates per frame: the same 24 replayed samples per frame).

Measurements (each with the training code itself: ``training.env_factory``,
``training.make_policy``, ``DDPGLearner.update``, ``training.train``):

* collection: the collector ``mivecc train`` builds (``collectors.make_collector``, one
  process) with the exploration policy (stage I: edge actor + noise; stage II: frozen edge
  actor + cloud actor + noise), frames/s of its batches after one warm-up batch (the time
  inside the collector: the copies kept for the learner timing are made outside it, as the
  training loop copies each batch into its replay buffer outside it);
* learner: updates/s and samples/s of the trained group on collected data, at the thread
  count each path uses (old: 1, the documented setting; new: ``thread_settings``);
* end-to-end (stage I): ``train()`` on 1x1 at the densities, frames/s between the end of its
  first iteration and its end (from ``train_log.csv``: steady state, past the warm-up).

Usage (the table in docs/performance.md and docs/training.md):
    python benchmarks/train_speed.py --repeats 2
"""

from __future__ import annotations

import csv
import os
import sys
import tempfile
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch (see thread_settings)

import torch

from mivecc_agents import training
from mivecc_agents.collectors import make_collector
from mivecc_agents.learner import DDPGLearner
from mivecc_agents.networks import make_actor, make_critic
from mivecc_agents.presets import get_preset, thread_settings
from mivecc_env import cli_args

#: (stage, grid rows = cols, densities) of the two stages, as the documented commands train.
STAGE_SETUPS = {"edge": (1, (900.0, 1500.0, 2100.0)), "cloud": (3, (1500.0,))}
OLD_PRESET = get_preset("stable").replace(batch_size=48, updates_per_frame=0.5)


def _preset(path: str, envs_per_density: int) -> Any:
    if path == "old":
        return OLD_PRESET
    return get_preset("stable").replace(envs_per_density=envs_per_density)


def _setup(stage: str, path: str, envs_per_density: int, seed: int = 0):
    """Env factory, collection policy, actor, critic and preset of one stage and path."""
    rc, dens = STAGE_SETUPS[stage]
    scheme = training.STAGES[stage]["scheme"]
    group = training.STAGES[stage]["group"]
    p = _preset(path, envs_per_density)
    overrides = {"rows": rc, "cols": rc, "max_steps": p.episode_steps}
    backend = "pettingzoo" if path == "old" else "native"
    env_fn, env_density = training.env_factory(
        backend, list(dens), overrides, scheme, p.envs_per_density, seed
    )
    from torchrl.modules import AdditiveGaussianModule

    probe = env_fn()
    spec = probe.full_action_spec[(group, "action")].clone()
    groups = training.env_groups(probe)
    probe.close(raise_if_closed=False)
    actor, critic = make_actor(group, group), make_critic(group, group)
    noise = AdditiveGaussianModule(spec=spec, action_key=(group, "action"))
    frozen = None
    if stage == "cloud":
        from mivecc_agents.policies import pretrained_path

        frozen = training.load_frozen_edge_actor(pretrained_path("edge"))
    policy = training.make_policy(stage, actor, noise, frozen, groups=groups)
    return env_fn, len(env_density), policy, actor, critic, p


def collect(stage: str, path: str, frames: int, steps_per_env: int, envs_per_density: int,
            keep: list | None = None) -> dict[str, float]:
    """Collection frames/s (after one warm-up batch); appends copies of the batches to
    ``keep`` (the collector yields its own buffer, overwritten by the next batch)."""
    env_fn, n_envs, policy, *_ = _setup(stage, path, envs_per_density)
    fpb = steps_per_env * n_envs
    torch.set_num_threads(1 if path == "old" else _threads(stage))
    col = make_collector(env_fn, policy, fpb, -1, 1, None)
    it = iter(col)
    first = next(it)
    if keep is not None:
        keep.append(first.clone())
    n, dt = 0, 0.0
    while n < frames:
        t0 = time.perf_counter()
        data = next(it)
        dt += time.perf_counter() - t0
        n += data.numel()
        if keep is not None:
            keep.append(data.clone())
    col.shutdown()
    return {"frames": n, "seconds": dt, "frames_per_s": n / dt, "n_envs": n_envs}


def learn(stage: str, path: str, data: list, seconds: float, threads: int | None = None,
          device: str = "cpu") -> dict[str, float]:
    """Updates/s and samples/s of ``DDPGLearner.update`` on collected data (``seconds`` long),
    at ``threads`` (default: the path's setting), networks and replay buffer on ``device``
    (each update ends with the losses read back, so a GPU's queue is drained in the time)."""
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

    group = training.STAGES[stage]["group"]
    _, _, _, actor, critic, p = _setup(stage, path, 1)
    actor.to(device)
    critic.to(device)
    if threads is None:
        threads = 1 if path == "old" else _threads(stage)
    torch.set_num_threads(threads)
    keys = training._buffer_keys(group)
    flat = torch.cat([d.select(*keys).reshape(-1) for d in data])
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(flat.numel(), device=device),
                                    batch_size=p.batch_size)
    buffer.extend(flat)
    learner = DDPGLearner(actor, critic, group, p)
    learner.update(buffer, 3)  # warm-up (allocations)
    n, t = 0, 0.0
    while t < seconds:
        stats = learner.update(buffer, 5)
        n += stats.n_updates
        t += stats.seconds
    return {"updates_per_s": n / t, "samples_per_s": n * p.batch_size / t,
            "batch_size": p.batch_size, "threads": torch.get_num_threads(), "device": device}


def end_to_end(path: str, frames: int, envs_per_density: int, steps_per_env: int
               ) -> dict[str, float]:
    """Stage-I ``train()`` frames/s over its iterations after the first (steady state)."""
    rc, dens = STAGE_SETUPS["edge"]
    p = _preset(path, envs_per_density).replace(frames_per_batch=steps_per_env)
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as out:
        training.train("edge", p, frames=frames, rows=rc, cols=rc, densities=list(dens),
                       seed=0, out_dir=out, progress=False,
                       backend="pettingzoo" if path == "old" else "native")
        with open(Path(out) / "train_log.csv") as fh:
            rows = list(csv.DictReader(fh))
    if len(rows) < 2:
        raise SystemExit(f"end-to-end {path}: need >= 2 iterations, got {len(rows)}; "
                         "raise --e2e-frames")
    f0, f1 = float(rows[0]["frames"]), float(rows[-1]["frames"])
    w0, w1 = float(rows[0]["wall_s"]), float(rows[-1]["wall_s"])
    return {"frames": f1 - f0, "seconds": w1 - w0, "frames_per_s": (f1 - f0) / (w1 - w0),
            "updates": sum(float(r["updates"]) for r in rows[1:])}


def _threads(stage: str) -> int:
    return int(thread_settings(stage)["OMP_NUM_THREADS"])


def _median(xs: list[float]) -> float:
    xs = sorted(xs)
    m = len(xs) // 2
    return xs[m] if len(xs) % 2 else 0.5 * (xs[m - 1] + xs[m])


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--stages", nargs="+", default=["edge", "cloud"], choices=["edge", "cloud"])
    parser.add_argument("--repeats", type=cli_args.count(1), default=2)
    parser.add_argument("--collect-frames", type=cli_args.count(1), nargs=2, default=[1200, 300],
                        metavar=("EDGE", "CLOUD"), help="old-path frames timed per repeat "
                        "(the new path times 10x as many)")
    parser.add_argument("--envs-per-density", type=cli_args.count(1), nargs=2, default=[16, 48],
                        metavar=("EDGE", "CLOUD"), help="new path: environments per density")
    parser.add_argument("--steps-per-env", type=cli_args.count(1), default=100,
                        help="collection: steps of each env per batch (the preset's 100)")
    parser.add_argument("--learn-seconds", type=cli_args.number(0.0, low_ok=False), default=4.0)
    parser.add_argument("--other-threads", action="store_true",
                        help="also time the new learner at the thread count not chosen "
                        "(OMP_WAIT_POLICY=PASSIVE)")
    parser.add_argument("--e2e-frames", type=cli_args.count(0), nargs=2, default=[2100, 24000],
                        metavar=("OLD", "NEW"), help="stage-I train() frames (0: skip)")
    parser.add_argument("--e2e-steps-per-env", type=cli_args.count(1), nargs=2, default=[100, 100],
                        metavar=("OLD", "NEW"), help="steps per env per iteration")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/train_speed"))
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    warnings.simplefilter("ignore")

    results: dict[tuple[str, str, str], list[float]] = {}
    extra: dict[tuple[str, str, str], dict] = {}

    def record(key: tuple[str, str, str], value: float, info: dict) -> None:
        results.setdefault(key, []).append(value)
        extra[key] = info
        print(f"  {key}: {value:.1f}  {info}", file=sys.stderr, flush=True)

    for rep in range(args.repeats):
        print(f"repeat {rep + 1}/{args.repeats}", file=sys.stderr, flush=True)
        for stage in args.stages:
            si = 0 if stage == "edge" else 1
            epd = args.envs_per_density[si]
            for path in ("old", "new"):
                frames = args.collect_frames[si] * (1 if path == "old" else 10)
                keep: list = []
                c = collect(stage, path, frames, args.steps_per_env, epd, keep)
                record((stage, path, "collect frames/s"), c["frames_per_s"], c)
                u = learn(stage, path, keep, args.learn_seconds)
                record((stage, path, "learner updates/s"), u["updates_per_s"], u)
                record((stage, path, "learner samples/s"), u["samples_per_s"], u)
                if path == "new" and args.other_threads:  # the thread count not chosen
                    other = 2 if _threads(stage) == 1 else 1
                    u = learn(stage, path, keep, args.learn_seconds, other)
                    record((stage, path, f"learner samples/s, {other} thread(s)"),
                           u["samples_per_s"], u)
        if "edge" in args.stages:
            for i, path in enumerate(("old", "new")):
                if args.e2e_frames[i] > 0:
                    e = end_to_end(path, args.e2e_frames[i], args.envs_per_density[0],
                                   args.e2e_steps_per_env[i])
                    record(("edge", path, "end-to-end frames/s"), e["frames_per_s"], e)

    lines = ["| stage | measure | old | new | new / old | settings (new) |",
             "|---|---|---|---|---|---|"]
    rows = []
    for stage in args.stages:
        for measure in ("collect frames/s", "learner updates/s", "learner samples/s",
                        "learner samples/s, 1 thread(s)", "learner samples/s, 2 thread(s)",
                        "end-to-end frames/s"):
            new = results.get((stage, "new", measure))
            old = results.get((stage, "old", measure.split(",")[0]))
            if not old or not new:
                continue
            mo, mn = _median(old), _median(new)
            info = extra[(stage, "new", measure)]
            settings = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                                 for k, v in info.items() if k in ("n_envs", "batch_size",
                                                                   "threads"))
            lines.append(f"| {stage} | {measure} | {mo:.1f} | {mn:.1f} | {mn / mo:.2f}x | "
                         f"{settings} |")
            rows.append({"stage": stage, "measure": measure, "old": mo, "new": mn,
                         "ratio": mn / mo, "old_all": old, "new_all": new})
    command = "python benchmarks/train_speed.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    text = f"Command: `{command.strip()}` ({args.repeats} repeats, medians)\n\n" + "\n".join(lines)
    return write_results(args.out, "train_speed", text, rows)


def write_results(out: Path, name: str, text: str, rows: list[dict]) -> dict[str, Any]:
    """Write ``<name>.md`` (``text``) and ``<name>.csv`` (``rows``) to ``out``, print ``text``;
    returns both."""
    (out / f"{name}.md").write_text(text + "\n")
    with open(out / f"{name}.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["stage"])
        writer.writeheader()
        writer.writerows(rows)
    print(text)
    return {"rows": rows, "text": text}


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
