"""A recipe sweep of PA-DQN (``mivecc train-signal``): each variant of the training command
trained with several seeds and compared by the training's own selection measure.

Each ``--variant NAME=OPTIONS`` is a list of ``mivecc train-signal`` options (``default=``
for none; ``--out``, ``--seed``, ``--threads``, ``--keep-network`` and ``--save-validated``
are set here) given to every training of the variant with each ``--seeds`` seed, one process
per training (``--workers`` at a time, one torch thread each), on the grid of ``--options``
common to all variants (e.g. ``--rows 3 --cols 3``). Every training keeps its best-validated
network (``keep_network="best"``); its validation score, the vehicles out per validation
environment of that network's greedy run (one environment per training density, seeds 1000
on), is what a variant is judged by: it measures the evaluation's vehicles out well
(docs/comparators.md, "Every validated PA-DQN network") without touching the evaluation
seeds. Evaluate a chosen variant's networks with ``benchmarks/learned_policies.py``.

Writes to ``--out``: one folder per training (``NAME_seedS``: ``signal_dqn.pt``,
``train_log.csv``, ``learning_curve.png``, ``output.txt`` with its stderr),
``signal_sweep.csv`` (one row per training), ``signal_sweep.md`` (per variant its options,
each seed's kept score, their mean and its difference to the first variant's; best mean
first) and ``signal_sweep.png`` (each training's kept score per variant). One progress bar
on stderr.

Usage (docs/comparators.md, "A recipe sweep of PA-DQN", has the committed run):
    python benchmarks/signal_sweep.py --variant default= "lr_3e-4=--lr 3e-4" \\
        "gamma_0.99=--gamma 0.99" --seeds 0 1 --workers 2 --out runs/signal_sweep
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import shlex
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from comparison import write_runs_and_tables

from mivecc_env import cli_args
from mivecc_env.processes import map_jobs

KEYS = ("variant", "options", "seed", "kept_episode", "kept_validation_throughput",
        "last_validation_throughput", "training_s")
#: Options the sweep sets itself.
RESERVED = ("--out", "--seed", "--threads", "--keep-network", "--save-validated")


def _variant(text: str) -> tuple[str, list[str]]:
    """``NAME=OPTIONS`` -> (name, the options split as a shell would)."""
    name, sep, options = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"must be NAME=OPTIONS, got {text!r}")
    try:
        argv = shlex.split(options)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None
    reserved = [a for a in argv if a.split("=")[0] in RESERVED]
    if reserved:
        raise argparse.ArgumentTypeError(f"{name}: {reserved[0]} is set by the sweep")
    return name, argv


def train_argv(options: Sequence[str], seed: int, out: Path) -> list[str]:
    """The ``mivecc`` arguments of one training."""
    return ["train-signal", *options, "--seed", str(seed), "--keep-network", "best",
            "--threads", "1", "--out", str(out)]


def check_options(option: str, argv: Sequence[str]) -> None:
    """:class:`~mivecc_env.cli_args.InputError` naming ``option`` if ``mivecc`` rejects
    ``argv`` or its training settings (parsed and checked only, nothing trained)."""
    from mivecc_agents.cli import build_parser
    from mivecc_agents.cli_signal import train_settings
    from mivecc_env.config import ConfigError

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            train_settings(build_parser().parse_args(list(argv)))
    except SystemExit:
        lines = [x for x in err.getvalue().splitlines() if x.strip()]
        raise cli_args.InputError(f"{option}: {lines[-1] if lines else 'rejected'}") from None
    except ConfigError as exc:
        raise cli_args.InputError(f"{option}: {exc}") from None


def _train(job: tuple[str, list[str], list[str], int, str]) -> dict[str, Any]:
    """One training (in its own process): its row of ``signal_sweep.csv``."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch
    from mivecc_agents import cli
    from mivecc_agents.signal_dqn import kept_episodes

    name, common, options, seed, out = job
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = cli.main(train_argv([*common, *options], seed, folder))
    (folder / "output.txt").write_text(err.getvalue(), encoding="utf-8")
    if status != 0:
        raise RuntimeError(f"{name} seed {seed}: mivecc train-signal exited {status} "
                           f"(see {folder / 'output.txt'})")
    with open(folder / "train_log.csv", newline="", encoding="utf-8") as fh:
        log = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]
    (_, episode, kept, last), = kept_episodes(log)
    return {"variant": name, "options": shlex.join(options), "seed": seed,
            "kept_episode": episode, "kept_validation_throughput": kept,
            "last_validation_throughput": last, "training_s": log[-1]["wall_s"]}


def summary(rows: Sequence[Mapping[str, Any]], seeds: Sequence[int], common: str) -> str:
    """The markdown of ``signal_sweep.md`` (module docstring); ``common``: the options of
    every variant."""
    variants = list(dict.fromkeys(r["variant"] for r in rows))

    def scores(name: str) -> list[float]:
        return [next(float(r["kept_validation_throughput"]) for r in rows
                     if r["variant"] == name and r["seed"] == s) for s in seeds]

    base = float(np.mean(scores(variants[0])))
    ranked = sorted(variants, key=lambda v: -float(np.mean(scores(v))))
    header = (f"Options of every variant: `{common}`." if common
              else "Every variant on the defaults but its own options.")
    lines = ["### Vehicles out per validation environment of the network each training keeps",
             "", header, "",
             "| variant | options | " + " | ".join(f"seed {s}" for s in seeds)
             + f" | mean | mean minus {variants[0]}'s | training [s] (mean) |",
             "|---" * (len(seeds) + 5) + "|"]
    for v in ranked:
        own = scores(v)
        options = next(r["options"] for r in rows if r["variant"] == v) or "(none)"
        wall = np.mean([float(r["training_s"]) for r in rows if r["variant"] == v])
        lines.append(f"| {v} | `{options}` | " + " | ".join(f"{x:.1f}" for x in own)
                     + f" | {np.mean(own):.1f} | {np.mean(own) - base:+.1f} | {wall:.0f} |")
    return "\n".join(lines) + "\n"


def figure(rows: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Each training's kept validation score per variant (one marker per seed, a bar at the
    mean)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mivecc_agents.signal_dqn import save_figure

    variants = list(dict.fromkeys(r["variant"] for r in rows))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(variants) + 2), 4.8))
    for i, v in enumerate(variants):
        own = [float(r["kept_validation_throughput"]) for r in rows if r["variant"] == v]
        ax.plot([i] * len(own), own, "o", color="tab:blue", alpha=0.7,
                label="one training (seed)" if i == 0 else None)
        ax.hlines(np.mean(own), i - 0.3, i + 0.3, color="tab:red",
                  label="mean over the seeds" if i == 0 else None)
    ax.set_xticks(range(len(variants)), variants, rotation=20, ha="right")
    ax.set_ylabel("kept network: vehicles out per validation environment")
    ax.set_title("PA-DQN recipe sweep: the validation score of the network each training keeps")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def main(argv: Sequence[str] | None = None) -> str:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--variant", dest="variants", nargs="+", type=_variant, required=True,
                   metavar="NAME=OPTIONS", help="train-signal options of a variant (the first "
                   "is the reference of the table's differences)")
    p.add_argument("--options", default="", help="train-signal options of every variant "
                   "(e.g. '--rows 3 --cols 3')")
    p.add_argument("--seeds", nargs="+", type=cli_args.seed, default=[0, 1])
    p.add_argument("--workers", type=cli_args.count(1), default=1)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/signal_sweep"))
    args = p.parse_args(argv)
    common = _variant(f"options={args.options}")[1]
    cli_args.check_distinct("--variant", [name for name, _ in args.variants])
    cli_args.check_distinct("--seeds", args.seeds)
    for name, options in args.variants:
        check_options(f"--variant {name}", train_argv([*common, *options], 0, args.out))
    cli_args.writable_dir("--out", args.out)
    jobs = [(name, common, options, seed, str(args.out / f"{name}_seed{seed}"))
            for name, options in args.variants for seed in args.seeds]
    rows = map_jobs(_train, jobs, args.workers, "training")
    text = summary(rows, args.seeds, shlex.join(common))
    write_runs_and_tables(args.out, "signal_sweep", KEYS, rows, "signal_sweep.py", argv, text)
    figure(rows, args.out / "signal_sweep.png")
    print(text)
    return text


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
