"""Every validated network of PA-DQN trainings, evaluated: how well the greedy validation run
(vehicles out) predicts the comparison, and what the network ``keep_network="best"`` keeps
gives and gives up.

Each ``--trainings DIR`` is the ``--out`` folder of ``mivecc train-signal --save-validated``
(``train_log.csv`` with the ``validation_throughput`` column, ``validated/episode_NN.pt``).
Every validated network runs the comparison's setting (``--grids``, default 3x3;
``--densities``, default 300-2100 veh/lane/h; ``--seeds`` 0 1 2; ``--steps`` 3000; the
keep-clear rule as in the comparison), one batch per network and grid. Two rules pick a
network per training from its validation runs: ``last`` (``keep_network="last"``) and
``best`` (``keep_network="best"``: the most vehicles out per validation environment, the
first of the best); beside them, in hindsight, the network with the most vehicles out and the
fastest one in the evaluation (no rule can know them: they show what the validation leaves).

Writes to ``--out``: ``validated_networks.csv`` (every run, with its network's validation
figure), ``validated_networks.md`` (per training and pick the network and its evaluation:
vehicles out, entry backlog and average travel velocity;
the correlations over the networks of validation and evaluation vehicles out, of validation
vehicles out and evaluation velocity, and of evaluation vehicles out and velocity; every
network's validation and evaluation) and ``validated_networks.png`` (evaluation vehicles out
against validation, evaluation velocity against evaluation vehicles out, one marker per
network). One progress bar on stderr.

Usage (docs/comparators.md, "Every validated PA-DQN network", has the committed runs):
    python benchmarks/validated_networks.py --trainings runs/pa_dqn_seed0 \\
        runs/pa_dqn_seed1 --workers 2 --out benchmarks/results/validated_networks
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from learned_policies import _run as run_policy
from validated_actors import finish_figure, pearson, study

from mivecc_env import cli_args

VALIDATION = ("validation_throughput",)
KEYS = ("training", "episode", *VALIDATION, "rows", "cols", "density", "seed",
        "avg_travel_velocity_mps", "collisions", "throughput", "backlog")

Pick = Callable[[Sequence[Mapping[str, Any]]], Mapping[str, Any]]


class Evaluation(NamedTuple):
    """A network's evaluation, means over its runs."""

    out: float  #: vehicles that left the network per run
    backlog: float  #: vehicles still waiting to enter at the end of a run
    velocity: float  #: average travel velocity of the vehicles out [m/s]


def _run(job: tuple[dict[str, Any], int, int, tuple[int, ...], int, tuple[int, ...]]
         ) -> list[dict[str, Any]]:
    """Every (density, seed) run of one network on one grid, as one batch (the comparison's
    keep-clear rule)."""
    network, rows, cols, densities, steps, seeds = job
    runs = run_policy(("pa-dqn", "", network["path"], rows, cols, densities, steps, seeds, {}))
    head = {k: network[k] for k in ("training", "episode", *VALIDATION)}
    return [{**head, **{k: run[k] for k in KEYS[3:]}, "density": int(run["density"])}
            for run in runs]


def evaluation(runs: Sequence[Mapping[str, Any]]) -> Evaluation:
    """The :class:`Evaluation` of ``runs``."""
    return Evaluation(*(float(np.mean([r[k] for r in runs]))
                        for k in ("throughput", "backlog", "avg_travel_velocity_mps")))


def picks(evaluated: Mapping[tuple[str, int], Evaluation]) -> dict[str, Pick]:
    """The rules (``last``, ``best``) and the hindsight picks, each choosing one of a
    training's validated networks (the first of the best); ``evaluated`` maps (training,
    episode) to its :class:`Evaluation`."""
    def judged(measure: str) -> Pick:
        return lambda rows: max(
            rows, key=lambda r: getattr(evaluated[r["training"], r["episode"]], measure))

    def kept(rows: Sequence[Mapping[str, Any]]) -> Mapping[str, Any]:
        from mivecc_agents.signal_dqn import kept_episodes  # the trainer's own rule

        (_, episode, _, _), = kept_episodes(rows)
        return next(r for r in rows if r["episode"] == episode)

    return {"last": lambda rows: rows[-1],
            "best (keep_network=best)": kept,
            "most out in the evaluation (hindsight)": judged("out"),
            "fastest in the evaluation (hindsight)": judged("velocity")}


def evaluations(networks: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]]
                ) -> dict[tuple[str, int], Evaluation]:
    """(training, episode) -> :func:`evaluation` of that network's runs."""
    return {(n["training"], n["episode"]): evaluation(
        [r for r in runs if (r["training"], r["episode"]) == (n["training"], n["episode"])])
        for n in networks}


def summary(networks: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]]) -> str:
    """The markdown of ``validated_networks.md`` (module docstring)."""
    evaluated = evaluations(networks, runs)
    trainings = list(dict.fromkeys(n["training"] for n in networks))
    chosen = {name: {t: pick([n for n in networks if n["training"] == t]) for t in trainings}
              for name, pick in picks(evaluated).items()}
    lines = ["### The network each rule keeps: episode / evaluation vehicles out / backlog "
             "[veh] / average travel velocity [m/s] (means over the runs)", "",
             "| training | " + " | ".join(chosen) + " |", "|---" * (len(chosen) + 1) + "|"]
    for t in trainings:
        cells = []
        for name in chosen:
            n = chosen[name][t]
            cells.append(f"{n['episode']} / {_cell(evaluated[t, n['episode']])}")
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    validation = np.array([n["validation_throughput"] for n in networks])
    out = np.array([evaluated[n["training"], n["episode"]].out for n in networks])
    velocity = np.array([evaluated[n["training"], n["episode"]].velocity for n in networks])
    lines += ["", f"Over the {len(networks)} networks the validation run's vehicles out and "
              f"the evaluation's correlate with {pearson(np.c_[validation, out])}; the "
              f"validation run's vehicles out and the evaluation's average travel velocity "
              f"with {pearson(np.c_[validation, velocity])}; the evaluation's vehicles out and "
              f"its average travel velocity with {pearson(np.c_[out, velocity])}.", "",
              "### Every validated network", "",
              "| training | episode | validation: vehicles out per environment | evaluation: "
              "vehicles out / backlog [veh] / velocity [m/s] | picked by |",
              "|---|---|---|---|---|"]
    for n in networks:
        by = ", ".join(name for name in chosen if chosen[name][n["training"]] is n)
        lines.append(f"| {n['training']} | {n['episode']} | {n['validation_throughput']:.1f} | "
                     f"{_cell(evaluated[n['training'], n['episode']])} | {by} |")
    return "\n".join(lines) + "\n"


def _cell(e: Evaluation) -> str:
    return f"{e.out:.1f} / {e.backlog:.1f} / {e.velocity:.3f}"


def figure(networks: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]],
           setting: str, path: Path) -> Path:
    """Evaluation vehicles out against validation, and evaluation velocity against evaluation
    vehicles out (on ``setting``, a title), one marker per network, the network
    ``keep_network="best"`` keeps ringed and the last one squared."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    evaluated = evaluations(networks, runs)
    rules = picks(evaluated)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    for i, t in enumerate(dict.fromkeys(n["training"] for n in networks)):
        own = [n for n in networks if n["training"] == t]
        out = [evaluated[t, n["episode"]].out for n in own]
        velocity = [evaluated[t, n["episode"]].velocity for n in own]
        kept = own.index(rules["best (keep_network=best)"](own))
        style = {"marker": "os^vD<>ph*"[i % 10], "ls": "", "ms": 6, "alpha": 0.8}
        for ax, x, y in ((axes[0], [n["validation_throughput"] for n in own], out),
                         (axes[1], out, velocity)):
            line, = ax.plot(x, y, label=t, **style)
            ax.plot([x[kept]], [y[kept]], "o", ms=15, mfc="none", color=line.get_color())
            ax.plot([x[-1]], [y[-1]], "s", ms=13, mfc="none", color=line.get_color())
    axes[0].set_xlabel("greedy validation run: vehicles out per environment")
    axes[0].set_ylabel("evaluation: vehicles out per run (mean)")
    axes[1].set_xlabel("evaluation: vehicles out per run (mean)")
    axes[1].set_ylabel("evaluation: average travel velocity [m/s] (mean over the runs)")
    axes[0].set_title("vehicles out (ring: kept by keep_network=best; square: the last)")
    axes[1].set_title("velocity against vehicles out in the evaluation")
    return finish_figure(fig, axes, "PA-DQN's validated networks: validation run against "
                         f"evaluation ({setting})", path)


def main(argv: Sequence[str] | None = None) -> str:
    return study(argv, "validated_networks.py", __doc__.splitlines()[0], "mivecc train-signal",
                 VALIDATION, KEYS, _run, summary, figure, grids=[(3, 3)])


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
