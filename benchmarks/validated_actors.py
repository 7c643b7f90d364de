"""Every validated actor of CoMADDPG trainings, evaluated: how well the greedy validation run
predicts the comparison, and which actor each selection rule keeps.

Each ``--trainings DIR`` is the ``--out`` folder of ``mivecc train-comaddpg --save-validated``
(``train_log.csv`` with the validation columns, ``validated/episode_NN.pt``). Every validated
actor runs the comparison's setting (``--grids``, default 3x3; ``--densities``, default 1200
1500 1800 2100 veh/lane/h, where the collisions are; ``--seeds`` 0 1 2; ``--steps`` 3000), one
batch per actor and grid. Three rules pick an actor per training from its validation runs:
``last`` (``keep_network="last"``), ``best`` (``keep_network="best"``: fewest strict collision
events, then the highest average travel velocity) and ``best by reward`` (fewest collision
events, then the highest reward per vehicle-step).

Writes to ``--out``: ``validated_actors.csv`` (every run, with its actor's validation
measures), ``validated_actors.md`` (per training and rule the actor kept and its evaluation;
every actor's validation and evaluation; the correlation of validation and evaluation
collision events, and of their velocities, over the actors) and ``validated_actors.png``
(evaluation against validation, collision events and velocity, one marker per actor). One
progress bar on stderr.

Usage (docs/comparators.md, "Keeping the best-validated actor", has the committed runs):
    python benchmarks/validated_actors.py --trainings runs/v/actions_seed0 \\
        runs/v/actions_seed1 --workers 2 --out benchmarks/results/validated_actors
"""

from __future__ import annotations

import csv
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from comparison import add_run_options, write_runs_and_tables

from mivecc_env import cli_args
from mivecc_env.processes import map_jobs

KEYS = ("training", "episode", "validation_collisions", "validation_velocity",
        "validation_reward", "rows", "cols", "density", "seed", "avg_travel_velocity_mps",
        "collisions", "throughput")
VALIDATION = ("validation_collisions", "validation_velocity", "validation_reward")


def by_reward(measures: Mapping[str, float]) -> tuple[float, float]:
    """The alternative rule: fewer collision events first, then the higher reward per
    vehicle-step (NaN ranks last)."""
    reward = measures["validation_reward"]
    return -measures["validation_collisions"], -math.inf if math.isnan(reward) else reward


def rules() -> dict[str, Callable[[Sequence[Mapping[str, float]]], Mapping[str, float]]]:
    """Selection rules: each picks one of a training's validated log rows (the first of the
    best)."""
    from mivecc_agents.comaddpg import validation_key

    return {"last": lambda rows: rows[-1],
            "best (keep_network=best)": lambda rows: max(rows, key=validation_key),
            "best by reward": lambda rows: max(rows, key=by_reward)}


def validated(training: Path,
              columns: Sequence[str] = VALIDATION) -> list[dict[str, Any]]:
    """A ``--save-validated`` training's validated log rows (those where ``columns[0]`` is
    not NaN: episode and the validation ``columns``), each with the path of its network; an
    error naming the folder if its log or a network file is missing."""
    from mivecc_agents.cli_signal import validated_checkpoint

    log = training / "train_log.csv"
    if not log.is_file():
        raise cli_args.InputError(f"--trainings: {training} has no train_log.csv")
    with open(log, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh)
                if not math.isnan(float(r.get(columns[0]) or math.nan))]
    if not rows:
        raise cli_args.InputError(f"--trainings: {training}'s log has no validation runs "
                                  "(trained with --keep-network last?)")
    out = []
    for r in rows:
        episode = int(float(r["episode"]))
        path = validated_checkpoint(training, episode)
        if not path.is_file():
            raise cli_args.InputError(f"--trainings: {path} is missing (train with "
                                      "--save-validated)")
        out.append({"training": training.name, "episode": episode, "path": str(path),
                    **{k: float(r[k]) for k in columns}})
    return out


def _run(job: tuple[dict[str, Any], int, int, tuple[int, ...], int, tuple[int, ...]]
         ) -> list[dict[str, Any]]:
    """Every (density, seed) run of one actor on one grid, as one batch."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch: one thread per worker
    from mivecc_agents.comaddpg import CoMADDPGPolicy
    from mivecc_agents.evaluation import evaluate_batch

    actor, rows, cols, densities, steps, seeds = job
    runs = evaluate_batch("comaddpg", rows, cols, [float(d) for d in densities], steps, seeds,
                          policies={"vehicle": CoMADDPGPolicy.load(actor["path"])},
                          progress=False, warn=False)
    head = {k: actor[k] for k in ("training", "episode", *VALIDATION)}
    return [{**head, "rows": rows, "cols": cols, **{k: run[k] for k in KEYS[7:]}}
            for run in runs]


def evaluation(runs: Sequence[Mapping[str, Any]]) -> tuple[float, float]:
    """Strict collision events (sum) and average travel velocity [m/s] (mean) of runs."""
    return (float(sum(r["collisions"] for r in runs)),
            float(np.mean([r["avg_travel_velocity_mps"] for r in runs])))


def pearson(pairs: np.ndarray) -> str:
    """``Pearson r = ...`` of the two columns of ``pairs``, or why it is undefined."""
    if len(pairs) < 2 or np.any(pairs.std(axis=0) == 0):
        return "no Pearson r (a column without variation)"
    return f"Pearson r = {np.corrcoef(pairs.T)[0, 1]:.2f}"


def summary(actors: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]]) -> str:
    """The markdown of ``validated_actors.md`` (module docstring)."""
    def runs_of(actor: Mapping[str, Any]) -> list[Mapping[str, Any]]:
        return [r for r in runs if (r["training"], r["episode"])
                == (actor["training"], actor["episode"])]

    trainings = list(dict.fromkeys(a["training"] for a in actors))
    picks = {name: {t: rule([a for a in actors if a["training"] == t]) for t in trainings}
             for name, rule in rules().items()}
    lines = ["### The actor each rule keeps: episode / evaluation strict collision events "
             "(sum) / average travel velocity [m/s] (mean over the runs)", "",
             "| training | " + " | ".join(picks) + " |", "|---" * (len(picks) + 1) + "|"]
    totals = {name: 0.0 for name in picks}
    for t in trainings:
        cells = []
        for name in picks:
            actor = picks[name][t]
            collisions, velocity = evaluation(runs_of(actor))
            totals[name] += collisions
            cells.append(f"{actor['episode']} / {collisions:.0f} / {velocity:.3f}")
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    lines.append("| all (collision events) | "
                 + " | ".join(f"{v:.0f}" for v in totals.values()) + " |")
    collisions = np.array([(a["validation_collisions"], evaluation(runs_of(a))[0])
                           for a in actors])
    velocities = np.array([(a["validation_velocity"], evaluation(runs_of(a))[1])
                           for a in actors])
    lines += ["", f"Over the {len(actors)} actors the validation run's strict collision events "
              f"and the evaluation's correlate with {pearson(collisions)}, their average "
              f"travel velocities with {pearson(velocities)}.", "",
              "### Every validated actor", "",
              "| training | episode | validation: collision events / velocity [m/s] / reward "
              "per vehicle-step | evaluation: collision events / velocity [m/s] | kept by |",
              "|---|---|---|---|---|"]
    for a in actors:
        collisions, velocity = evaluation(runs_of(a))
        kept = ", ".join(name for name in picks if picks[name][a["training"]] is a)
        lines.append(f"| {a['training']} | {a['episode']} | {a['validation_collisions']:.0f} / "
                     f"{a['validation_velocity']:.3f} / {a['validation_reward']:.4f} | "
                     f"{collisions:.0f} / {velocity:.3f} | {kept} |")
    return "\n".join(lines) + "\n"


def figure(actors: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]],
           setting: str, path: Path) -> Path:
    """Evaluation (on ``setting``, a title) against validation (collision events; velocity),
    one marker per actor, the actor ``keep_network="best"`` keeps ringed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    best = rules()["best (keep_network=best)"]
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    trainings = list(dict.fromkeys(a["training"] for a in actors))
    for i, t in enumerate(trainings):
        own = [a for a in actors if a["training"] == t]
        evaluated = [evaluation([r for r in runs if (r["training"], r["episode"])
                                 == (t, a["episode"])]) for a in own]
        kept = own.index(best(own))
        style = {"marker": "os^vD<>ph*"[i % 10], "ls": "", "ms": 6, "alpha": 0.8}
        for ax, x, y in ((axes[0], [a["validation_collisions"] for a in own],
                          [e[0] for e in evaluated]),
                         (axes[1], [a["validation_velocity"] for a in own],
                          [e[1] for e in evaluated])):
            line, = ax.plot(x, y, label=t, **style)
            ax.plot([x[kept]], [y[kept]], "o", ms=15, mfc="none", color=line.get_color())
    axes[0].set_xscale("symlog", linthresh=1)
    axes[0].set_yscale("symlog", linthresh=1)
    axes[0].set_xlabel("greedy validation run: strict collision events\n(all its "
                       "environments)")
    axes[0].set_ylabel("evaluation: strict collision events (sum over the runs)")
    axes[1].set_xlabel("greedy validation run: average travel velocity [m/s]")
    axes[1].set_ylabel("evaluation: average travel velocity [m/s] (mean over the runs)")
    axes[0].set_title("collisions (ring: the actor keep_network=best keeps)")
    axes[1].set_title("velocity")
    return finish_figure(fig, axes, "CoMADDPG's validated actors: validation run against "
                         f"evaluation ({setting})", path)


def study(argv: Sequence[str] | None, script: str, description: str, command: str,
          columns: Sequence[str], keys: Sequence[str], run: Callable[[Any], list[Any]],
          summarise: Callable[[list[Any], list[Any]], str],
          draw: Callable[[list[Any], list[Any], str, Path], Path],
          **defaults: Any) -> str:
    """The command line of a study of every validated network of some ``--save-validated``
    trainings (this script's, ``validated_networks.py``'s): parse and check the arguments
    (the comparison's run options, ``defaults`` over them), evaluate every network of
    :func:`validated` (validation ``columns``) with ``run`` on every grid, write
    ``<stem>.csv`` (``keys``) and ``<stem>.md`` (``summarise``'s text) and ``<stem>.png``
    (``draw``) to ``--out``, print the text and return it; ``command``: the training command
    the trainings come from, ``script``: ``<stem>.py``, ``description``: its help line."""
    stem = Path(script).stem
    p = cli_args.Parser(description=description)
    p.add_argument("--trainings", nargs="+", type=Path, required=True, metavar="DIR",
                   help=f"--out folders of `{command} --save-validated`")
    add_run_options(p)
    p.set_defaults(**defaults)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results") / stem)
    args = p.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    for option in ("grids", "seeds", "densities"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))
    cli_args.check_distinct("--trainings", [t.name for t in args.trainings])
    networks = [n for t in args.trainings for n in validated(t, columns)]
    jobs = [(n, r, c, tuple(args.densities), args.steps, tuple(args.seeds))
            for n in networks for r, c in args.grids]
    runs = [row for batch in map_jobs(run, jobs, args.workers, "network x grid")
            for row in batch]
    text = summarise(networks, runs)
    write_runs_and_tables(args.out, stem, keys, runs, script, argv, text)
    setting = (f"{', '.join(f'{r}x{c}' for r, c in args.grids)}, "
               f"{', '.join(map(str, args.densities))} veh/lane/h, seeds "
               f"{', '.join(map(str, args.seeds))}, {args.steps} steps")
    draw(networks, runs, setting, args.out / f"{stem}.png")
    print(text)
    return text


def finish_figure(fig: Any, axes: Sequence[Any], title: str, path: Path) -> Path:
    """Title, grids and the legend (right of the second panel) of a study's two-panel
    figure; saved to ``path``."""
    from mivecc_agents.signal_dqn import save_figure

    fig.suptitle(title)
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(fig, path)


def main(argv: Sequence[str] | None = None) -> str:
    return study(argv, "validated_actors.py", __doc__.splitlines()[0], "mivecc train-comaddpg",
                 VALIDATION, KEYS, _run, summary, figure, grids=[(3, 3)],
                 densities=[1200, 1500, 1800, 2100])


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
