"""Policy files of a learned comparator side by side on the comparison's setting.

``--scheme`` is ``comaddpg`` (default), ``pa-dqn`` or ``coder``. Each policy (``NAME=FILE``, or
``NAME=shipped`` for the scheme's shipped policy of each grid, the default) runs every grid,
density and seed of the comparison (1x1 and 3x3, 300..2100 veh/lane/h, seeds 0-2, 3000 steps;
Coder only on grids of at least 2x2), one batch per policy and grid (a batch gives each run's
single result, tested). One markdown table per grid gives each policy's average travel
velocity (mean over the seeds), its strict collision events (sum) and the vehicles that left
the network (mean), beside the committed
runs of ``--reference-schemes`` (default MiVeCC-EEC) from a comparison CSV (``--reference``)
where it holds them. Writes ``learned_policies.csv`` (every run), ``learned_policies.md`` and
``learned_policies.png`` (velocity and strict events against the demand) to ``--out`` and
prints the tables; one progress bar on stderr.

Usage (docs/comparators.md, "Training seeds and a fuller critic" and "Training seeds of the
learned signal comparators", have the committed runs):
    python benchmarks/learned_policies.py --scheme pa-dqn --grids 1x1 --policies \\
        seed0=shipped seed1=runs/pa_dqn_seed1/signal_dqn.pt --workers 2 \\
        --out benchmarks/results/learned_policies
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from comparison import (
    SIGNAL_KEEP_CLEAR,
    SIGNAL_SCHEMES,
    add_run_options,
    made_with_keep_clear,
    runs_on,
    write_runs_and_tables,
)

from mivecc_agents.cli import parse_set_items
from mivecc_env import cli_args
from mivecc_env.processes import map_jobs

KEYS = ("policy", "rows", "cols", "density", "seed", "avg_travel_velocity_mps", "collisions",
        "throughput", "backlog")
SCHEMES = ("comaddpg", "pa-dqn", "coder")
SHIPPED = "shipped"


def _load(scheme: str, path: str, rows: int, cols: int) -> dict[str, Any]:
    """The ``policies`` argument of one run: the file's policy, or the shipped one."""
    from mivecc_agents.evaluation import shipped_comparator_policies

    if path == SHIPPED:
        return shipped_comparator_policies(scheme, rows, cols)
    if scheme == "comaddpg":
        from mivecc_agents.comaddpg import CoMADDPGPolicy

        return {"vehicle": CoMADDPGPolicy.load(path)}
    from mivecc_agents.signal_policy_files import load_signal_policy

    return {"signal": load_signal_policy(path)}


def _run(job: tuple[str, str, str, int, int, tuple[int, ...], int, tuple[int, ...],
                    dict[str, Any]]) -> list[dict[str, Any]]:
    """Every (density, seed) run of one policy on one grid, as one batch."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch: one thread per worker
    from mivecc_agents.evaluation import evaluate_batch

    scheme, name, path, rows, cols, densities, steps, seeds, overrides = job
    runs = evaluate_batch(scheme, rows, cols, [float(d) for d in densities], steps, seeds,
                          policies=_load(scheme, path, rows, cols), progress=False, warn=False,
                          **overrides)
    return [{"policy": name, **{key: run[key] for key in KEYS[1:]}} for run in runs]


def reference_label(scheme: str) -> str:
    """A reference scheme's column name (MiVeCC's schemes with the name in front)."""
    return f"MiVeCC-{scheme}" if scheme in ("E", "EE", "EEC") else f"{scheme} (committed)"


def reference_runs(path: Path | None, schemes: Sequence[str], steps: int,
                   keep_clear: bool = SIGNAL_KEEP_CLEAR) -> list[dict[str, Any]]:
    """The runs of ``schemes`` of ``steps`` steps in a comparison CSV (none without a file);
    of the signal controllers only those made with the keep-clear rule ``keep_clear``, the
    policies' (like for like)."""
    if path is None:
        return []
    with open(path, newline="", encoding="utf-8") as fh:
        return [{"policy": reference_label(r["scheme"]), "rows": int(r["rows"]),
                 "cols": int(r["cols"]), "density": int(float(r["density"])),
                 "seed": int(r["seed"]),
                 **{key: float(r[key]) for key in KEYS[5:]}}
                for r in csv.DictReader(fh) if r["scheme"] in schemes
                and int(r["steps"]) == steps
                and (r["scheme"] not in SIGNAL_SCHEMES or made_with_keep_clear(r) == keep_clear)]


def tables(rows: list[dict[str, Any]], names: Sequence[str], grids: Sequence[tuple[int, int]],
           densities: Sequence[int], seeds: Sequence[int]) -> str:
    """Per grid: average travel velocity [m/s] (mean over the seeds) / strict collision events
    (sum) / throughput [veh] (mean), per policy and density; a column only where it has every
    seed's run."""
    lines = []
    for r, c in grids:
        cols = [n for n in names if all(
            any((x["policy"], x["rows"], x["cols"], x["density"], x["seed"]) == (n, r, c, d, s)
                for x in rows) for d in densities for s in seeds)]
        lines += [f"### {r}x{c}: average travel velocity [m/s] (mean over seeds "
                  f"{', '.join(map(str, seeds))}) / strict collision events (sum) / vehicles out "
                  f"(mean)", "",
                  "| density [veh/lane/h] | " + " | ".join(cols) + " |",
                  "|---" * (len(cols) + 1) + "|"]
        for d in densities:
            cells = [str(d)]
            for n in cols:
                runs = [x for x in rows if (x["policy"], x["rows"], x["cols"], x["density"])
                        == (n, r, c, d) and x["seed"] in seeds]
                cells.append(f"{np.mean([x['avg_travel_velocity_mps'] for x in runs]):.3f} / "
                             f"{sum(x['collisions'] for x in runs):.0f} / "
                             f"{np.mean([x['throughput'] for x in runs]):.0f}")
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def figure(rows: list[dict[str, Any]], names: Sequence[str], grids: Sequence[tuple[int, int]],
           densities: Sequence[int], seeds: Sequence[int], path: Path) -> Path:
    """A PNG per :func:`tables`: for each grid, the average travel velocity (mean over the
    seeds) and the strict collision events (sum) against the density, one line per policy
    (references dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mivecc_agents.signal_dqn import save_figure

    fig, axes = plt.subplots(2, len(grids), figsize=(6.5 * len(grids), 7.5), squeeze=False,
                             sharex=True)
    for col, (r, c) in enumerate(grids):
        for i, name in enumerate(names):
            runs = [[x for x in rows if (x["policy"], x["rows"], x["cols"], x["density"])
                     == (name, r, c, d) and x["seed"] in seeds] for d in densities]
            if not all(len(cell) == len(seeds) for cell in runs):
                continue
            style = {"ls": "--" if "(committed)" in name or name.startswith("MiVeCC-") else "-",
                     "marker": "os^vD<>ph*"[i % 10], "ms": 4, "label": name}
            axes[0, col].plot(densities, [np.mean([x["avg_travel_velocity_mps"] for x in cell])
                                          for cell in runs], **style)
            axes[1, col].plot(densities, [sum(x["collisions"] for x in cell) for cell in runs],
                              **style)
        axes[0, col].set_title(f"{r}x{c} (seeds {', '.join(map(str, seeds))})")
        axes[0, col].set_ylabel("average travel velocity [m/s]\n(mean over the seeds)")
        axes[1, col].set_ylabel("strict collision events\n(sum over the seeds)")
        axes[1, col].set_xlabel("demand [veh/lane/h]")
        for ax in axes[:, col]:
            ax.grid(alpha=0.3)
    axes[0, -1].legend(fontsize=8, loc="best")
    return save_figure(fig, path)


def _policy(text: str) -> tuple[str, str]:
    """``NAME=FILE`` (an existing file) or ``NAME=shipped``."""
    name, sep, path = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"must be NAME=FILE or NAME={SHIPPED}, got {text!r}")
    return name, path if path == SHIPPED else str(cli_args.existing_file(path))


def main(argv: Sequence[str] | None = None) -> str:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--scheme", choices=SCHEMES, default="comaddpg")
    p.add_argument("--policies", nargs="+", type=_policy, metavar="NAME=FILE",
                   default=[(SHIPPED, SHIPPED)],
                   help=f"policy files; NAME={SHIPPED}: the scheme's shipped one per grid")
    add_run_options(p)
    p.add_argument("--reference", type=cli_args.existing_file,
                   default=Path("docs/results/comparison/comparison.csv"),
                   help="comparison CSV with the reference schemes' runs (default: the "
                   "committed one); signal controllers' runs only where made with the "
                   "policies' keep-clear rule")
    p.add_argument("--reference-schemes", nargs="+", default=["EEC"],
                   help="schemes of --reference shown beside the policies (default EEC)")
    p.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", default=[],
                   help="config fields of the policies' runs (not of the reference runs), "
                   "e.g. signal_keep_clear=false")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/learned_policies"))
    args = p.parse_args(argv)
    overrides = parse_set_items(args.set_items)
    cli_args.writable_dir("--out", args.out)
    for option in ("grids", "seeds", "densities", "reference_schemes"):
        cli_args.check_distinct(f"--{option.replace('_', '-')}", getattr(args, option))
    names = [name for name, _ in args.policies]
    cli_args.check_distinct("--policies", names)
    grids = [(r, c) for r, c in args.grids if runs_on(args.scheme, r, c)]
    if not grids:
        raise cli_args.InputError(f"--grids: scheme {args.scheme} runs on none of them "
                                  "(Coder needs 2x2 or larger)")
    jobs = [(args.scheme, name, path, r, c, tuple(args.densities), args.steps,
             tuple(args.seeds), overrides) for (r, c) in grids for name, path in args.policies]
    rows = [run for runs in map_jobs(_run, jobs, args.workers, "policy x grid")
            for run in runs]
    for row in rows:
        row["density"] = int(row["density"])
    reference = reference_runs(args.reference, args.reference_schemes, args.steps,
                               bool(overrides.get("signal_keep_clear", SIGNAL_KEEP_CLEAR)))
    labels = [*names, *(reference_label(s) for s in args.reference_schemes)]
    text = tables(rows + reference, labels, grids, args.densities, args.seeds)
    write_runs_and_tables(args.out, "learned_policies", KEYS, rows, "learned_policies.py", argv,
                          text)
    figure(rows + reference, labels, grids, args.densities, args.seeds,
           args.out / "learned_policies.png")
    print(text)
    return text


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
