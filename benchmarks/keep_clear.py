"""Signals with and without the keep-clear rule (``signal_keep_clear``), paired by seed.

Every signal scheme (fixed-time, actuated, max-pressure, PA-DQN and Coder with their shipped
policies; Coder on grids of at least 2x2) runs on the same seeded demand twice, with the rule
off and on (the default since session 45); one markdown table per grid gives each scheme's
strict collision events summed over the seeds and its mean average travel velocity and
throughput, off -> on. Writes ``keep_clear.csv`` (every run) and ``keep_clear.md`` to ``--out``
and prints the tables; one progress bar on stderr.

Usage (the committed run, docs/comparators.md "Keeping the box clear"):
    python benchmarks/keep_clear.py --grids 1x1 3x3 --seeds 0 1 2 --steps 3000 --workers 2 \\
        --out docs/results/keep_clear
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from comparison import add_run_options, runs_on, write_runs_and_tables

from mivecc_env import cli_args
from mivecc_env.processes import map_jobs

SCHEMES = ("fixed-time", "actuated", "max-pressure", "pa-dqn", "coder")
#: Columns of ``keep_clear.csv`` (with ``steps``, it serves as a reference CSV of
#: ``learned_policies.py`` for either rule).
KEYS = ("scheme", "rows", "cols", "density", "seed", "steps", "signal_keep_clear",
        "avg_travel_velocity_mps", "collisions", "throughput", "backlog")


def _run(job: tuple[str, int, int, float, int, int, bool]) -> dict[str, Any]:
    """One episode of a signal scheme, the rule on or off."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch: one thread per worker
    from mivecc_agents.evaluation import evaluate_scheme, shipped_comparator_policies

    scheme, rows, cols, density, steps, seed, keep_clear = job
    policies = shipped_comparator_policies(scheme, rows, cols)
    out = evaluate_scheme(scheme, rows, cols, density, steps, seed, policies=policies,
                          progress=False, warn=False, signal_keep_clear=keep_clear)
    return {key: out.get(key, keep_clear) for key in KEYS}


def tables(rows: list[dict[str, Any]], grids: Sequence[tuple[int, int]],
           densities: Sequence[int]) -> str:
    """Per grid: strict events (sum over seeds), velocity [m/s] and throughput [veh] (means),
    rule off -> on, per scheme and density."""
    lines = []
    for r, c in grids:
        schemes = [s for s in SCHEMES if runs_on(s, r, c)]
        lines += [f"### {r}x{c}: strict collision events (sum over the seeds) / average travel "
                  "velocity [m/s] / throughput [veh] (means), keep-clear off -> on", "",
                  "| density | " + " | ".join(schemes) + " |",
                  "|---" * (len(schemes) + 1) + "|"]
        for d in densities:
            cells = [str(d)]
            for s in schemes:
                pair = []
                for rule in (False, True):
                    runs = [x for x in rows if (x["scheme"], x["rows"], x["cols"], x["density"],
                                                x["signal_keep_clear"]) == (s, r, c, d, rule)]
                    pair.append((int(sum(x["collisions"] for x in runs)),
                                 np.mean([x["avg_travel_velocity_mps"] for x in runs]),
                                 np.mean([x["throughput"] for x in runs])))
                (e0, v0, t0), (e1, v1, t1) = pair
                cells.append(f"{e0} -> {e1} / {v0:.2f} -> {v1:.2f} / {t0:.0f} -> {t1:.0f}")
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> str:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    add_run_options(p)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/keep_clear"))
    args = p.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    for option in ("grids", "seeds", "densities"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))
    jobs = [(s, r, c, float(d), args.steps, seed, rule) for (r, c) in args.grids
            for s in SCHEMES if runs_on(s, r, c) for d in args.densities for seed in args.seeds
            for rule in (False, True)]
    rows = map_jobs(_run, jobs, args.workers, "runs")
    for row in rows:
        row["density"] = int(row["density"])
    text = tables(rows, args.grids, args.densities)
    write_runs_and_tables(args.out, "keep_clear", KEYS, rows, "keep_clear.py", argv, text)
    print(text)
    return text


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
