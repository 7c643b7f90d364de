"""How many validation environments CoMADDPG's ``keep_network="best"`` needs: every validated
actor of some trainings revalidated on up to ``max(--envs)`` environments, and the actor the
default rule keeps with each number of them, beside its evaluation.

Each ``--trainings DIR`` is the ``--out`` folder of ``mivecc train-comaddpg --save-validated``;
``--evaluation CSV`` is ``validated_actors.csv`` of ``benchmarks/validated_actors.py`` for the
same trainings (every actor's evaluation runs). Every validated actor runs one greedy validation
(``mivecc_agents.comaddpg.validation_runs``: its training's settings, densities cycled over the
environments, seeds 1000 on, ``--steps`` steps, default the training's ``validation_steps``) on
``max(--envs)`` environments; an environment's run does not depend on the others, so the first
N of them are the validation with ``validation_envs = N``. For each N the default rule
(``validation_key``: fewest strict collision events, then the highest average travel velocity)
picks an actor per training.

Writes to ``--out``: ``validation_size.csv`` (every actor's every validation environment),
``validation_size.md`` (per N: the actor kept per training with its evaluation, their total
evaluation collision events and mean velocity, how the actors without a validation collision
fared, the correlation of validation and evaluation collision events) and
``validation_size.png`` (the kept actors' evaluation against N, the last actors for reference).
One progress bar on stderr.

Usage (docs/comparators.md, "How many validation environments", has the committed runs):
    python benchmarks/validation_size.py --trainings runs/v/actions_seed0 \\
        runs/v/actions_seed1 \\
        --evaluation benchmarks/results/validated_actors/validated_actors.csv --workers 2 \\
        --out benchmarks/results/validation_size
"""

from __future__ import annotations

import csv
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from comparison import write_runs_and_tables
from validated_actors import evaluation, pearson, validated

from mivecc_env import cli_args
from mivecc_env.processes import map_jobs

KEYS = ("training", "episode", "env", "density", "seed", "collisions", "avg_travel_velocity_mps",
        "throughput", "reward_sum", "transitions")
#: Default numbers of validation environments compared (multiples of the 7 training densities).
ENVS = (7, 14, 21, 28, 42)


def _revalidate(job: tuple[dict[str, Any], int, int | None]) -> list[dict[str, Any]]:
    """One actor's validation on ``envs`` environments: one row per environment."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch: one thread per worker
    from mivecc_agents.comaddpg import (
        VALIDATION_SEED,
        CoMADDPGPolicy,
        CoMADDPGSettings,
        validation_env,
        validation_runs,
    )

    actor, envs, steps = job
    policy = CoMADDPGPolicy.load(actor["path"])
    saved = dict(policy.settings)
    saved["densities"] = tuple(saved["densities"])
    if steps is not None:
        saved["validation_steps"] = steps
    settings = CoMADDPGSettings(**saved).check()
    runs = validation_runs(settings, validation_env(settings, settings.env_config(), envs),
                           policy.actor)
    densities = settings.densities
    return [{"training": actor["training"], "episode": actor["episode"], "env": i,
             "density": densities[i % len(densities)], "seed": VALIDATION_SEED + i,
             "collisions": int(runs.collisions[i]),
             "avg_travel_velocity_mps": float(runs.velocity[i]),
             "throughput": float(runs.throughput[i]), "reward_sum": float(runs.reward_sum[i]),
             "transitions": int(runs.transitions[i])} for i in range(envs)]


def measures(rows: Sequence[Mapping[str, Any]], envs: int) -> dict[str, float]:
    """The validation measures of one actor's first ``envs`` environments (its rows of
    ``validation_size.csv``), as ``ValidationRuns.measures`` gives them."""
    from mivecc_agents.comaddpg import ValidationRuns

    part = sorted((r for r in rows if int(r["env"]) < envs), key=lambda r: int(r["env"]))
    if len(part) < envs:
        raise cli_args.InputError(f"--envs: {envs} environments asked, {len(part)} validated")
    col = {k: np.array([float(r[k]) for r in part]) for k in KEYS[5:]}
    return ValidationRuns(col["collisions"], col["reward_sum"], col["transitions"],
                          col["avg_travel_velocity_mps"], col["throughput"]).measures()


def read_evaluation(path: Path) -> dict[tuple[str, int], list[dict[str, Any]]]:
    """The runs of ``validated_actors.csv`` by (training, episode)."""
    if not path.is_file():
        raise cli_args.InputError(f"--evaluation: {path} is not a file")
    out: dict[tuple[str, int], list[dict[str, Any]]] = {}
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            try:
                run = {"collisions": float(r["collisions"]),
                       "avg_travel_velocity_mps": float(r["avg_travel_velocity_mps"])}
                key = (r["training"], int(float(r["episode"])))
            except (KeyError, ValueError) as exc:
                raise cli_args.InputError(f"--evaluation: {path} is not a validated_actors.csv"
                                          f" ({exc})") from exc
            out.setdefault(key, []).append(run)
    return out


#: Per number of validation environments: each training's kept actor, and every actor.
Kept = dict[int, tuple[dict[str, dict[str, Any]], list[dict[str, Any]]]]


def kept_by_size(actors: Sequence[Mapping[str, Any]], rows: Sequence[Mapping[str, Any]],
                 sizes: Sequence[int]) -> Kept:
    """For each number of environments: each training's actor the default rule keeps (the
    first of the best, as the trainer does) and every actor, each with its ``measures`` under
    ``"validation"``."""
    from mivecc_agents.comaddpg import validation_key

    own: dict[tuple[str, int], list[Mapping[str, Any]]] = {}
    for r in rows:
        own.setdefault((r["training"], int(r["episode"])), []).append(r)
    out = {}
    for n in sizes:
        scored = [{**a, "validation": measures(own[a["training"], a["episode"]], n)}
                  for a in actors]
        picks = {t: max((a for a in scored if a["training"] == t),  # max: the first of the best
                        key=lambda a: validation_key(a["validation"]))
                 for t in dict.fromkeys(a["training"] for a in scored)}
        out[n] = (picks, scored)
    return out


def summary(actors: Sequence[Mapping[str, Any]], kept: Kept,
            evaluated: Mapping[tuple[str, int], Sequence[Mapping[str, Any]]]) -> str:
    """The markdown of ``validation_size.md`` (module docstring) from :func:`kept_by_size`."""
    trainings = list(dict.fromkeys(a["training"] for a in actors))
    sizes = list(kept)

    def ev(a: Mapping[str, Any]) -> tuple[float, float]:
        return evaluation(evaluated[a["training"], a["episode"]])

    last = {t: [a for a in actors if a["training"] == t][-1] for t in trainings}
    lines = ["### The actor kept with N validation environments: episode / evaluation strict "
             "collision events (sum) / average travel velocity [m/s] (mean over the runs)", "",
             "| N | " + " | ".join(trainings) + " | all: collision events / mean velocity "
             "[m/s] | actors without a validation collision: number / their evaluation "
             "collision events | validation vs evaluation collision events |",
             "|---" * (len(trainings) + 4) + "|"]
    for label, picks, scored in (
            [("last", last, None)]
            + [(str(n), *kept[n]) for n in sizes]):
        cells = [f"{picks[t]['episode']} / {ev(picks[t])[0]:.0f} / {ev(picks[t])[1]:.3f}"
                 for t in trainings]
        total = sum(ev(picks[t])[0] for t in trainings)
        mean_velocity = float(np.mean([ev(picks[t])[1] for t in trainings]))
        if scored is None:
            clean, corr = "", ""
        else:
            zero = [ev(a)[0] for a in scored if a["validation"]["validation_collisions"] == 0]
            clean = f"{len(zero)}" + (f" / {min(zero):.0f}-{max(zero):.0f}" if zero else "")
            corr = pearson(np.array([(a["validation"]["validation_collisions"], ev(a)[0])
                                     for a in scored]))
        lines.append(f"| {label} | " + " | ".join(cells)
                     + f" | {total:.0f} / {mean_velocity:.3f} | {clean} | {corr} |")
    return "\n".join(lines) + "\n"


def figure(actors: Sequence[Mapping[str, Any]], kept: Kept,
           evaluated: Mapping[tuple[str, int], Sequence[Mapping[str, Any]]],
           path: Path) -> Path:
    """The kept actors' total evaluation collision events and mean velocity against N
    (:func:`kept_by_size`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mivecc_agents.signal_dqn import save_figure

    trainings = list(dict.fromkeys(a["training"] for a in actors))
    sizes = list(kept)
    last = [[a for a in actors if a["training"] == t][-1] for t in trainings]

    def ev(group: Sequence[Mapping[str, Any]]) -> tuple[float, float]:
        pairs = [evaluation(evaluated[a["training"], a["episode"]]) for a in group]
        return sum(p[0] for p in pairs), float(np.mean([p[1] for p in pairs]))

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    for ax, i, label in ((axes[0], 0, "evaluation: strict collision events\n(sum over the "
                          "kept actors' runs)"),
                         (axes[1], 1, "evaluation: average travel velocity [m/s]\n(mean "
                          "over the kept actors)")):
        ax.plot(sizes, [ev([kept[n][0][t] for t in trainings])[i] for n in sizes], "o-",
                label="kept actor (keep_network=best)")
        ax.axhline(ev(last)[i], color="grey", ls="--", label="last actor (keep_network=last)")
        ax.set_xlabel("validation environments (validation_envs)")
        ax.set_ylabel(label)
        ax.set_xticks(list(sizes))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylim(bottom=0)
    fig.suptitle(f"CoMADDPG: the actor kept by the validation of N environments "
                 f"({len(trainings)} trainings)")
    return save_figure(fig, path)


def main(argv: Sequence[str] | None = None) -> str:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--trainings", nargs="+", type=Path, required=True, metavar="DIR",
                   help="--out folders of `mivecc train-comaddpg --save-validated`")
    p.add_argument("--evaluation", type=Path, required=True, metavar="CSV",
                   help="validated_actors.csv of benchmarks/validated_actors.py for them")
    p.add_argument("--envs", type=cli_args.count(1), nargs="+", default=list(ENVS),
                   help=f"numbers of validation environments (default "
                   f"{' '.join(map(str, ENVS))})")
    p.add_argument("--steps", type=cli_args.count(1), default=None,
                   help="steps of each validation run (default: the training's "
                   "validation_steps)")
    p.add_argument("--workers", type=cli_args.count(1), default=1,
                   help="processes (default 1)")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/validation_size"))
    args = p.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    cli_args.check_distinct("--envs", args.envs)
    cli_args.check_distinct("--trainings", [t.name for t in args.trainings])
    sizes = sorted(args.envs)
    evaluated = read_evaluation(args.evaluation)
    actors = [a for t in args.trainings for a in validated(t)]
    missing = [f"{a['training']} {a['episode']}" for a in actors
               if (a["training"], a["episode"]) not in evaluated]
    if missing:
        raise cli_args.InputError(f"--evaluation: no runs of {', '.join(missing)}")
    jobs = [(a, sizes[-1], args.steps) for a in actors]
    rows = [r for batch in map_jobs(_revalidate, jobs, args.workers, "actor")
            for r in batch]
    kept = kept_by_size(actors, rows, sizes)
    text = summary(actors, kept, evaluated)
    write_runs_and_tables(args.out, "validation_size", KEYS, rows, "validation_size.py", argv,
                          text)
    figure(actors, kept, evaluated, args.out / "validation_size.png")
    print(text)
    return text


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
