"""DDPG learner throughput per device and thread count: would a GPU speed up training?

For each stage, batches are collected once with the training code's collector (the new path
of ``train_speed.py``: the native batched env, the default preset), then
``DDPGLearner.update`` runs on them for ``--learn-seconds`` in every setting, round-robin over
``--repeats``: each device of ``--devices`` (networks and replay buffer there; ``cuda`` needs a
GPU) at each thread count of ``--threads`` (torch's intra-op threads). Reported: updates/s
and samples/s (medians), and each setting's ratio to the first one.

Usage:
    python benchmarks/learner_devices.py --devices cpu cuda --threads 1 2 --repeats 3
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from mivecc_env import cli_args

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("train_speed", HERE / "train_speed.py")
assert _spec is not None and _spec.loader is not None
train_speed = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(train_speed)  # the benchmarks folder is not a package


def _device(text: str) -> str:
    """Argument type: a device ``mivecc train --device`` accepts (``training.learner_device``)."""
    from mivecc_agents.training import TrainingError, learner_device

    try:
        learner_device(text, "value")
    except TrainingError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("value: ")) from None
    return text


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--stages", nargs="+", default=["edge", "cloud"],
                        choices=["edge", "cloud"])
    parser.add_argument("--devices", nargs="+", type=_device,
                        default=["cpu"])
    parser.add_argument("--threads", nargs="+", type=cli_args.count(1), default=[1, 2])
    parser.add_argument("--repeats", type=cli_args.count(1), default=3)
    parser.add_argument("--collect-frames", type=cli_args.count(1), nargs=2,
                        default=[12000, 3000], metavar=("EDGE", "CLOUD"),
                        help="frames collected once per stage for the learner")
    parser.add_argument("--envs-per-density", type=cli_args.count(1), nargs=2, default=[16, 48],
                        metavar=("EDGE", "CLOUD"))
    parser.add_argument("--learn-seconds", type=cli_args.number(0.0, low_ok=False),
                        default=3.0)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/learner_devices"))
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    warnings.simplefilter("ignore")
    settings = [(d, t) for d in args.devices for t in args.threads]

    results: dict[tuple[str, str, int], list[float]] = {}
    batch: dict[str, int] = {}
    for stage in args.stages:
        si = 0 if stage == "edge" else 1
        keep: list = []
        torch.set_num_threads(1)
        train_speed.collect(stage, "new", args.collect_frames[si], 100,
                            args.envs_per_density[si], keep)
        for rep in range(args.repeats):
            for device, threads in settings:
                u = train_speed.learn(stage, "new", keep, args.learn_seconds, threads, device)
                results.setdefault((stage, device, threads), []).append(u["samples_per_s"])
                batch[stage] = u["batch_size"]
                print(f"  {stage} {device} {threads} thread(s), repeat {rep + 1}: "
                      f"{u['updates_per_s']:.1f} updates/s, {u['samples_per_s']:.0f} samples/s",
                      file=sys.stderr, flush=True)

    lines = ["| stage | device | threads | updates/s | samples/s | vs first |",
             "|---|---|---:|---:|---:|---:|"]
    rows = []
    for stage in args.stages:
        first = train_speed._median(results[(stage, *settings[0])])
        for device, threads in settings:
            med = train_speed._median(results[(stage, device, threads)])
            lines.append(f"| {stage} | {device} | {threads} | {med / batch[stage]:.1f} | "
                         f"{med:.0f} | {med / first:.2f}x |")
            rows.append({"stage": stage, "device": device, "threads": threads,
                         "batch_size": batch[stage], "samples_per_s": med,
                         "ratio": med / first, "all": results[(stage, device, threads)]})
    gpu = torch.cuda.get_device_name(0) if "cuda" in {d for d, _ in settings} else "none"
    command = "python benchmarks/learner_devices.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    text = (f"Command: `{command.strip()}` ({args.repeats} repeats, medians; GPU: {gpu})\n\n"
            + "\n".join(lines))
    return train_speed.write_results(args.out, "learner_devices", text, rows)


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
