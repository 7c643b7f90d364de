"""The paper's comparison figures: every scheme against MiVeCC and the upper bound.

For each grid (single intersection 1x1, 3x3), density and seed, every scheme of
:data:`mivecc_agents.evaluation.SCHEMES` (MiVeCC E / EE / EEC with the shipped coordinators, the
signal controllers, reservation and optimisation) runs one evaluation episode on the same
seeded demand. Writes to ``--out``:

* ``comparison.csv``: one row per run (the JSON keys of ``mivecc evaluate``),
* ``comparison.md``: per grid, the mean average travel velocity of every scheme and the upper
  bound per density, the collisions (summed over the seeds) and the max-pressure vs fixed-time
  gain,
* ``comparison_<grid>.png``: average travel velocity and collisions vs density.

Runs already in a CSV given with ``--from-csv`` (e.g. ``docs/results/paper_table/paper_table.csv``
for E, EE, EEC and fixed-time, its ``signalized``) are reused when grid, scheme, density, seed
and steps match, so only the missing runs are simulated.

Usage (one command; progress on stderr):
    python benchmarks/comparison.py --grids 1x1 3x3 --seeds 0 1 2 --steps 3000 --workers 2
"""

from __future__ import annotations

import argparse
import csv
import multiprocessing as mp
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

SCHEMES = ("E", "EE", "EEC", "fixed-time", "actuated", "max-pressure", "reservation",
           "optimisation")
DENSITIES = (300, 600, 900, 1200, 1500, 1800, 2100)
#: Older name of a scheme in earlier CSVs.
ALIASES = {"signalized": "fixed-time"}


def _run(job: tuple[str, int, int, float, int, int]) -> dict[str, Any]:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch: one thread per episode
    from mivecc_agents.evaluation import evaluate_scheme

    scheme, rows, cols, density, steps, seed = job
    policies = {}
    if scheme in ("EE", "EEC"):
        from mivecc_agents.policies import pretrained_policies

        policies = pretrained_policies()
    return evaluate_scheme(scheme, rows, cols, density, steps, seed, policies=policies,
                           progress=False, warn=False)


def _key(row: dict[str, Any]) -> tuple:
    scheme = ALIASES.get(str(row["scheme"]), str(row["scheme"]))
    return (scheme, int(float(row["rows"])), int(float(row["cols"])),
            int(float(row["density"])), int(float(row["seed"])), int(float(row["steps"])))


def load_rows(paths: Sequence[Path]) -> dict[tuple, dict[str, Any]]:
    """Earlier runs by (scheme, rows, cols, density, seed, steps)."""
    out: dict[tuple, dict[str, Any]] = {}
    for path in paths:
        with open(path, newline="", encoding="utf-8") as f:
            for row in csv.DictReader(f):
                row = dict(row)
                row["scheme"] = ALIASES.get(row["scheme"], row["scheme"])
                out[_key(row)] = row
    return out


def _mean(rows: list[dict[str, Any]], key: str) -> tuple[float, float]:
    vals = np.array([float(r[key]) for r in rows])
    return float(vals.mean()), float(vals.std())


def markdown(rows: list[dict[str, Any]], grids: Sequence[tuple[int, int]],
             schemes: Sequence[str], densities: Sequence[int]) -> str:
    """Tables of mean velocity (and collisions) per grid, density and scheme."""
    lines = []
    for r, c in grids:
        sub = [x for x in rows if int(float(x["rows"])) == r and int(float(x["cols"])) == c]
        if not sub:
            continue
        seeds = sorted({int(float(x["seed"])) for x in sub})
        steps = sorted({int(float(x["steps"])) for x in sub})
        lines += [f"### {r}x{c}: average travel velocity [m/s] (mean over seeds {seeds}, "
                  f"{'/'.join(map(str, steps))} steps); collisions summed over the seeds in "
                  "brackets; n = runs where fewer than the seeds", ""]
        lines.append("| density | " + " | ".join(schemes) + " | upper bound | max-pressure vs "
                     "fixed-time (same seeds) |")
        lines.append("|---" * (len(schemes) + 3) + "|")
        for d in densities:
            cells = [str(d)]
            bound = ""
            for s in schemes:
                runs = [x for x in sub if x["scheme"] == s and int(float(x["density"])) == d]
                if not runs:
                    cells.append("")
                    continue
                v = _mean(runs, "avg_travel_velocity_mps")[0]
                coll = int(sum(float(x["collisions"]) for x in runs))
                few = f" n={len(runs)}" if len(runs) < len(seeds) else ""
                cells.append(f"{v:.2f} ({coll}){few}")
                bound = f"{float(runs[0]['upper_bound_mps']):.2f}"
            gain = ""
            by_seed = {s: {int(float(x["seed"])): float(x["avg_travel_velocity_mps"])
                           for x in sub if x["scheme"] == s and int(float(x["density"])) == d}
                       for s in ("fixed-time", "max-pressure")}
            common = sorted(set(by_seed["fixed-time"]) & set(by_seed["max-pressure"]))
            if common:  # on the seeds both have
                mp_v = np.mean([by_seed["max-pressure"][k] for k in common])
                ft_v = np.mean([by_seed["fixed-time"][k] for k in common])
                gain = f"{100.0 * (mp_v / ft_v - 1.0):+.1f} %" if ft_v > 0 else ""
            lines.append("| " + " | ".join([*cells, bound, gain]) + " |")
        lines.append("")
    return "\n".join(lines)


def plot(rows: list[dict[str, Any]], grid: tuple[int, int], schemes: Sequence[str],
         densities: Sequence[int], path: Path) -> None:
    """Velocity and collisions vs density of every scheme, with the upper bound."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r, c = grid
    sub = [x for x in rows if int(float(x["rows"])) == r and int(float(x["cols"])) == c]
    if not sub:
        return
    fig, (ax_v, ax_c) = plt.subplots(1, 2, figsize=(12, 4.5))
    bound = None
    for s in schemes:
        xs, ms, sds, cs = [], [], [], []
        for d in densities:
            runs = [x for x in sub if x["scheme"] == s and int(float(x["density"])) == d]
            if runs:
                m, sd = _mean(runs, "avg_travel_velocity_mps")
                xs.append(d)
                ms.append(m)
                sds.append(sd)
                cs.append(sum(float(x["collisions"]) for x in runs))
                bound = float(runs[0]["upper_bound_mps"])
        if xs:
            label = f"MiVeCC-{s}" if s in ("E", "EE", "EEC") else s
            ax_v.errorbar(xs, ms, yerr=sds, marker="o", capsize=3, label=label)
            ax_c.plot(xs, cs, marker="o", label=label)
    if bound is not None:
        ax_v.axhline(bound, color="k", ls="--", label="upper bound")
    ax_v.set_xlabel("density [veh/lane/h]")
    ax_v.set_ylabel("average travel velocity [m/s]")
    ax_v.set_title(f"{r}x{c}: average travel velocity")
    ax_v.legend(fontsize=8)
    ax_c.set_xlabel("density [veh/lane/h]")
    ax_c.set_ylabel("collisions (sum over seeds)")
    ax_c.set_yscale("symlog")
    ax_c.set_title(f"{r}x{c}: collisions (strict: any two vehicles < 2 m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--grids", nargs="+", default=["1x1", "3x3"])
    p.add_argument("--schemes", nargs="+", default=list(SCHEMES), choices=SCHEMES)
    p.add_argument("--densities", nargs="+", type=int, default=list(DENSITIES))
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--steps", type=int, default=3000, help="env steps of 0.1 s per run")
    p.add_argument("--steps-for", nargs="+", default=[], metavar="SCHEME=STEPS",
                   help="fewer steps for a slow scheme, e.g. optimisation=1000")
    p.add_argument("--workers", type=int, default=1, help="processes (1: in this process)")
    p.add_argument("--from-csv", nargs="+", type=Path, default=[],
                   help="reuse matching runs of earlier CSVs")
    p.add_argument("--tabulate-only", action="store_true",
                   help="simulate nothing: tables and figures of the runs found in --from-csv")
    p.add_argument("--out", type=Path, default=Path("docs/results/comparison"))
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    grids = [tuple(int(x) for x in g.lower().split("x")) for g in args.grids]
    steps_for = {k: int(v) for k, v in (item.split("=") for item in args.steps_for)}
    known = load_rows(args.from_csv)
    args.out.mkdir(parents=True, exist_ok=True)
    jobs, rows = [], []
    for (r, c) in grids:
        for d in args.densities:
            for s in args.schemes:
                for seed in args.seeds:
                    steps = steps_for.get(s, args.steps)
                    key = (s, r, c, d, seed, steps)
                    if key in known:
                        rows.append(known[key])
                    else:
                        jobs.append((s, r, c, float(d), steps, seed))
    if args.tabulate_only:
        jobs = []
    print(f"{len(rows)} runs reused, {len(jobs)} to simulate", flush=True)
    csv_path = args.out / "comparison.csv"
    if jobs and args.workers <= 1:
        for job in tqdm(jobs, desc="runs"):
            rows.append(_run(job))
            _write_csv(rows, csv_path)
    elif jobs:
        with mp.get_context("spawn").Pool(args.workers) as pool:
            for res in tqdm(pool.imap_unordered(_run, jobs), total=len(jobs), desc="runs"):
                rows.append(res)
                _write_csv(rows, csv_path)
    _write_csv(rows, csv_path)
    md = markdown(rows, grids, args.schemes, args.densities)
    (args.out / "comparison.md").write_text(md + "\n", encoding="utf-8")
    for g in grids:
        plot(rows, g, args.schemes, args.densities, args.out / f"comparison_{g[0]}x{g[1]}.png")
    print(md)
    return 0


def _write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in sorted(rows, key=_key):
            w.writerow(r)


if __name__ == "__main__":
    raise SystemExit(main())
