"""The paper's efficiency comparison: E, EE, EEC, a signalized baseline and Coder over densities.

For every grid, density, scheme and seed this runs one evaluation episode with the shipped
pretrained coordinators (or the checkpoints given with ``--edge`` / ``--cloud``); all densities
and seeds of a (grid, scheme) run as one batch of environments
(:func:`mivecc_agents.evaluation.evaluate_batch`; a learned policy is called once on the
stacked batch where a check finds that exact (``stack_policies=True``), as the committed tables
were made; on real graphs that can still round an action differently in rare steps, and that
run then differs from its single run; with ``--per-env-calls`` every run equals its single run
bit for bit, about 1.4x the time for the README's tables), then
writes

* ``paper_table.csv`` - one row per run,
* ``paper_table.md`` - per grid and density: mean average travel velocity of each scheme, the
  upper bound, collisions, and the improvement rates EE vs E, EEC vs E, EEC vs EE, EEC vs the
  signalized baseline and EEC vs Coder (the shipped Coder policy, on grids of at least 2x2)
  next to the paper's Table (3x3),
* ``velocity_vs_density_<grid>.png`` - average travel velocity vs density per scheme with the
  upper bound,
* ``gains_<grid>.png`` - the gains in per cent vs density, paired by seed, in average travel
  and released-style velocity: each scheme over MiVeCC-E and EEC over EE, the paper's values
  (3x3) marked,
* a learned cloud runs with the ``cloud_period`` recorded in its checkpoint (the ``EEC+3``
  ceiling's constant cloud decides every step),
* in ``paper_table.md`` also, per grid: the released-style velocity (entry to 5 m past the last
  intersection centre, no entry wait; its improvement rates) and the near-miss measures of
  every scheme (``mivecc_env.sim.near_miss``).
* ``--set KEY=VALUE ...`` changes config fields for every run (e.g. ``cloud_graphs=per_lane``,
  the paper's per-lane cloud graphs); the CSV rows record them,
* ``machine.json`` - the CPU, libraries and commit the runs were made on (a line of it heads
  ``paper_table.md``): runs with a learned policy reproduce bit for bit on the same kind of CPU,
  not across CPUs (``benchmarks/table_diff.py`` compares two tables).

Usage (the full table; 252 episodes in 12 batches; then Coder's 21 runs, merged):
    python benchmarks/paper_table.py --grids 1x1 3x3 --seeds 0 1 2 --steps 3000 --workers 2
    python benchmarks/paper_table.py --grids 3x3 --schemes coder --seeds 0 1 2 --steps 3000 \
        --workers 1 --out benchmarks/results/paper_table/coder_runs
    python benchmarks/paper_table.py --grids 1x1 3x3 --from-csv \
        benchmarks/results/paper_table/paper_table.csv \
        benchmarks/results/paper_table/coder_runs/paper_table.csv
"""

from __future__ import annotations

import csv
import itertools
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from machine_info import describe, machine_info

from mivecc_env import cli_args
from mivecc_env.config import from_overrides
from mivecc_env.processes import map_jobs

SCHEMES = ("signalized", "E", "EE", "EEC", "EE+3", "EEC+3", "coder")
#: What runs without ``--schemes``: every scheme but Coder (``--schemes coder`` adds its runs,
#: merged with ``--from-csv``: the published tables were made without it; it needs a 2x2 grid).
DEFAULT_SCHEMES = SCHEMES[:-1]
#: Constant-action ceilings: the scheme run, and the coordinator replaced by a constant +3 m/s^2
#: (EE+3: every edge action +3; EEC+3: the learned edge and a cloud that always sends +3).
CEILINGS: dict[str, tuple[str, str]] = {"EE+3": ("EE", "edge"), "EEC+3": ("EEC", "cloud")}
DENSITIES = (300, 600, 900, 1200, 1500, 1800, 2100)

#: The paper's Table eff_imp_rate (3x3 grid), improvement of the average velocity [%].
PAPER_3X3: dict[str, dict[int, float]] = {
    "EEC vs Coder": dict(zip(DENSITIES, (
        79.80, 85.10, 146.63, 283.32, 352.26, 419.48, 459.09), strict=True)),
    "EE vs E": dict(zip(DENSITIES, (0.14, 0.40, 0.52, 0.91, 1.47, 1.92, 2.12), strict=True)),
    "EEC vs E": dict(zip(DENSITIES, (0.37, 1.00, 1.56, 1.96, 2.32, 2.76, 2.96), strict=True)),
    "EEC vs EE": dict(zip(DENSITIES, (0.23, 0.6, 1.03, 1.04, 0.84, 0.83, 0.82), strict=True)),
}
COMPARISONS = (("EE", "E"), ("EEC", "E"), ("EEC", "EE"), ("EEC", "signalized"),
               ("EE+3", "E"), ("EEC+3", "EE"), ("EEC", "coder"))


def _run(job: tuple[str, int, int, list[float], int, list[int], str | None, str | None, str,
                    int | None, dict[str, Any], bool]) -> list[dict[str, Any]]:
    """All densities and seeds of one (scheme, grid) as one batch of environments."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch: one thread per worker
    from mivecc_agents.evaluation import evaluate_batch
    from mivecc_agents.policies import ceiling_policy, pretrained_policies

    (scheme, rows, cols, densities, steps, seeds, edge_path, cloud_path, model, cloud_period,
     overrides, per_env_calls) = job
    config = from_overrides(model=model, **overrides)
    policies = pretrained_policies(model, edge=edge_path, cloud=cloud_path,
                                   safety_shield=config.safety_shield)
    run_scheme = scheme
    if scheme == "coder":  # the shipped Coder policy of the grid (signal agents)
        from mivecc_agents.evaluation import shipped_comparator_policies

        policies = shipped_comparator_policies(scheme, rows, cols)
    if scheme in CEILINGS:
        run_scheme, kind = CEILINGS[scheme]
        policies[kind] = ceiling_policy(kind, config)
    # a learned cloud decides at the period it was trained with (evaluate_batch adopts it),
    # the constant cloud of EEC+3 every step, unless --cloud-period names the period of both
    extra = {"cloud_period": cloud_period} if cloud_period and run_scheme == "EEC" else {}
    out = evaluate_batch(run_scheme, rows, cols, densities, steps, seeds, policies=policies,
                         progress=False, warn=False, stack_policies=not per_env_calls,
                         model=model, **overrides, **extra)
    for row in out:
        row.update(overrides)
        row.update(scheme=scheme, model=model)
    return out


def read_runs_csv(path: Path) -> list[dict[str, Any]]:
    """Rows of an earlier run's CSV with the numeric columns parsed."""
    def parse(value: Any) -> Any:
        if not isinstance(value, str):  # a row with more fields than the header: a list
            return value
        try:
            number = float(value)
        except ValueError:
            return value
        return int(number) if number.is_integer() and "." not in value else number

    with open(path, newline="") as fh:
        return [{k: parse(v) for k, v in row.items()} for row in csv.DictReader(fh)]


#: What identifies one run of the table (a later CSV's run replaces an earlier one's).
RUN_KEY = ("rows", "cols", "scheme", "density", "seed")


def merge_runs(files: Sequence[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """The runs of several CSV files, a later file's run replacing an earlier one with the same
    :data:`RUN_KEY` (in the earlier one's place); runs of one file are all kept."""
    merged: dict[tuple[Any, ...], dict[str, Any]] = {}
    for runs in files:
        fresh: dict[tuple[Any, ...], dict[str, Any]] = {}
        for row in runs:
            key = tuple(row.get(k) for k in RUN_KEY)
            if key in fresh:  # the same key twice in one file: keep both
                key = (*key, len(merged) + len(fresh))
            fresh[key] = row
        merged.update(fresh)
    return list(merged.values())


def improvement(new: float, old: float) -> float:
    """Relative improvement of ``new`` over ``old`` [%]."""
    return 100.0 * (new - old) / old if old > 0 else float("nan")


def cell_runs(rows: list[dict[str, Any]], grid: str) -> dict[tuple[str, float], list[dict]]:
    """The runs of one grid (``ROWSxCOLS``) by ``(scheme, density)``, in the order given."""
    r, c = (int(x) for x in grid.split("x"))
    cells: dict[tuple[str, float], list[dict[str, Any]]] = {}
    for x in rows:
        if (x["rows"], x["cols"]) == (r, c):
            cells.setdefault((x["scheme"], x["density"]), []).append(x)
    return cells


def summarise(rows: list[dict[str, Any]], grid: str) -> tuple[str, dict]:
    """Markdown table of one grid and the per-(scheme, density) means."""
    cells = cell_runs(rows, grid)
    densities = sorted({d for _, d in cells})
    schemes = [s for s in SCHEMES if any(k == s for k, _ in cells)]
    mean: dict[tuple[str, float], dict[str, float]] = {}
    for s, d in itertools.product(schemes, densities):
        runs = cells.get((s, d))
        if runs:
            mean[(s, d)] = {
                "v": float(np.mean([x["avg_travel_velocity_mps"] for x in runs])),
                "v_sd": float(np.std([x["avg_travel_velocity_mps"] for x in runs])),
                "collisions": float(np.sum([x["collisions"] for x in runs])),
                "ub": float(runs[0]["upper_bound_mps"]),
                "n": len(runs),
                "actions": runs[0]["coordinator_actions"],
            }
    head = "| veh/lane/h | upper bound | " + " | ".join(
        f"{s} v [m/s] (collisions)" for s in schemes) + " | " + " | ".join(
        f"{a} vs {b} [%]" for a, b in COMPARISONS if a in schemes and b in schemes) + " |"
    lines = [f"### {grid}", "", head, "|" + "---|" * (head.count("|") - 1)]
    for d in densities:
        cells = [f"{d:.0f}", f"{mean[(schemes[0], d)]['ub']:.3f}"]
        cells += [f"{mean[(s, d)]['v']:.3f} ± {mean[(s, d)]['v_sd']:.3f} "
                  f"({mean[(s, d)]['collisions']:.0f})" for s in schemes]
        for a, b in COMPARISONS:
            if a in schemes and b in schemes:
                ours = improvement(mean[(a, d)]["v"], mean[(b, d)]["v"])
                cells.append(f"{ours:+.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    if grid == "3x3":
        lines += ["", "The paper's Table (3x3), improvement of the average velocity [%]:", "",
                  "| comparison | " + " | ".join(str(d) for d in DENSITIES) + " |",
                  "|" + "---|" * (len(DENSITIES) + 1)]
        for name, values in PAPER_3X3.items():
            lines.append(f"| {name} | " + " | ".join(f"{values[d]:.2f}" for d in DENSITIES)
                         + " |")
    actions = {s: mean[(s, densities[0])]["actions"] for s in schemes}
    lines += ["", f"Coordinator actions per scheme: {actions}; ± is the standard deviation over "
              f"{mean[(schemes[0], densities[0])]['n']} seeds; collisions are summed over seeds."]
    return "\n".join(lines), mean


#: Near-miss keys of the second table: (column, key, how runs of a cell are combined).
NEAR_MISS_COLUMNS = (
    ("min TTC [s]", "min_ttc_s", "min"), ("TTC 1st pct [s]", "ttc_p1_s", "mean"),
    ("min PET [s]", "min_pet_s", "min"), ("PET < 1 s", "pet_under_1s", "sum"),
    ("min distance [m]", "min_distance_m", "min"),
)


def near_miss_table(rows: list[dict[str, Any]], grid: str) -> str:
    """Markdown: released-style velocity, its improvement rates and the near-miss measures.

    Empty when the runs predate these keys (e.g. an old ``--from-csv`` file).
    """
    cells = cell_runs(rows, grid)
    if not cells or any(x.get("released_velocity_mps", "") == ""
                        for runs in cells.values() for x in runs):
        return ""
    densities = sorted({d for _, d in cells})
    schemes = [s for s in SCHEMES if any(k == s for k, _ in cells)]
    combine = {"min": np.min, "mean": np.mean, "sum": np.sum}
    cell: dict[tuple[str, float], dict[str, float]] = {}
    for s, d in itertools.product(schemes, densities):
        runs = cells.get((s, d))
        if runs:
            cell[(s, d)] = {"rv": float(np.mean([float(x["released_velocity_mps"])
                                                 for x in runs]))}
            for _, key, how in NEAR_MISS_COLUMNS:
                cell[(s, d)][key] = float(combine[how]([float(x[key]) for x in runs]))
    pairs = [(a, b) for a, b in COMPARISONS if a in schemes and b in schemes]
    head = ("| veh/lane/h | " + " | ".join(f"{s} released-style v [m/s]" for s in schemes)
            + "".join(f" | {a} vs {b} [%]" for a, b in pairs) + " |")
    lines = [f"### {grid}: released-style velocity (entry to 5 m past the last centre)", "",
             head, "|" + "---|" * (head.count("|") - 1)]
    for d in densities:
        cells = [f"{d:.0f}"] + [f"{cell[(s, d)]['rv']:.3f}" for s in schemes]
        cells += [f"{improvement(cell[(a, d)]['rv'], cell[(b, d)]['rv']):+.2f}" for a, b in pairs]
        lines.append("| " + " | ".join(cells) + " |")
    head = "| scheme | veh/lane/h | " + " | ".join(n for n, _, _ in NEAR_MISS_COLUMNS) + " |"
    lines += ["", f"### {grid}: near-miss measures", "", head,
              "|" + "---|" * (head.count("|") - 1)]
    for s, d in itertools.product(schemes, densities):
        if (s, d) in cell:
            values = [f"{cell[(s, d)][key]:.3f}" if how != "sum" else f"{cell[(s, d)][key]:.0f}"
                      for _, key, how in NEAR_MISS_COLUMNS]
            lines.append(f"| {s} | {d:.0f} | " + " | ".join(values) + " |")
    lines += ["", "Over the seeds: the smallest minima, the mean 1st-percentile TTC, the summed "
              "count of PET samples below 1 s; definitions in `mivecc_env/sim/near_miss.py`."]
    return "\n".join(lines)


#: Fixed colour of each scheme in every figure (matplotlib's default cycle, in SCHEMES order).
COLOURS = {s: f"C{i}" for i, s in enumerate(SCHEMES)}

#: Panels of the gains figure: (base scheme, schemes compared with it, the paper's rows marked
#: as scheme -> name in PAPER_3X3).
GAIN_PANELS: tuple[tuple[str, tuple[str, ...], dict[str, str]], ...] = (
    ("E", ("EE", "EEC", "EE+3"), {"EE": "EE vs E", "EEC": "EEC vs E"}),
    ("EE", ("EEC", "EEC+3"), {"EEC": "EEC vs EE"}),
)

#: Velocity metrics of the gains figure: (CSV key, name).
GAIN_METRICS = (("avg_travel_velocity_mps", "average travel velocity"),
                ("released_velocity_mps", "released-style velocity"))


def plot(mean: dict, grid: str, path: Path, note: str = "") -> None:
    """Average travel velocity vs density per scheme (mean ± sd over seeds), with the upper
    bound."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4.5))
    ax = fig.add_subplot()
    schemes = sorted({s for s, _ in mean}, key=SCHEMES.index)
    for s in schemes:
        ds = sorted(d for t, d in mean if t == s)
        ax.errorbar(ds, [mean[(s, d)]["v"] for d in ds], yerr=[mean[(s, d)]["v_sd"] for d in ds],
                    marker="o", capsize=3, label=_label(s), color=COLOURS[s],
                    linestyle="--" if s in CEILINGS else "-")
    ds = sorted({d for _, d in mean})
    ax.plot(ds, [mean[(schemes[0], d)]["ub"] for d in ds], "k--", label="upper bound")
    ax.set_xlabel("density [veh/lane/h]")
    ax.set_ylabel("average travel velocity [m/s]")
    ax.set_title(f"Average travel velocity vs density, {grid} grid{note}")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_gains(rows: list[dict[str, Any]], grid: str, path: Path, note: str = "") -> bool:
    """Gains in per cent vs density, paired by seed: one row of panels per velocity metric
    (average travel velocity; the released-style velocity when the runs have it), left each
    scheme over MiVeCC-E, right EEC over EE; mean ± sd over seeds, every seed a dot, the
    paper's Table values (3x3) as crosses. Returns False (and writes nothing) when no pair of
    runs can be compared."""
    from matplotlib.figure import Figure

    # per metric, the gains of each panel; a metric no run pair has gets no row
    per_metric = {name: [_paired_gains(rows, grid, key, base, compared)
                         for base, compared, _ in GAIN_PANELS] for key, name in GAIN_METRICS}
    metrics = {name: panels for name, panels in per_metric.items() if any(panels)}
    if not metrics:
        return False
    height = 4.8 * len(metrics) + 1.0  # [in]; the last inch holds the legend
    fig = Figure(figsize=(13, height))
    axes = fig.subplots(len(metrics), len(GAIN_PANELS), squeeze=False, sharex=True)
    for m, ((name, panels), row_axes) in enumerate(zip(metrics.items(), axes, strict=True)):
        for (base, _, paper), gains, ax in zip(GAIN_PANELS, panels, row_axes, strict=True):
            for s, per_d in gains.items():
                ds = sorted(per_d)
                ax.errorbar(ds, [float(np.mean(per_d[d])) for d in ds],
                            yerr=[float(np.std(per_d[d])) for d in ds], marker="o", capsize=3,
                            color=COLOURS[s], linestyle="--" if s in CEILINGS else "-",
                            label=f"{_label(s)} (mean ± sd over seeds)")
                for d in ds:
                    ax.plot([d] * len(per_d[d]), per_d[d], ".", color=COLOURS[s], alpha=0.4)
            if grid == "3x3":
                for s, table_row in paper.items():
                    if s in gains:
                        ax.plot(list(DENSITIES), [PAPER_3X3[table_row][d] for d in DENSITIES],
                                "x", markersize=9, mew=2, color=COLOURS[s],
                                label=f"paper: MiVeCC-{table_row}")
            ax.axhline(0.0, color="k", lw=0.8)
            if m == len(metrics) - 1:
                ax.set_xlabel("density [veh/lane/h]")
            ax.set_ylabel(f"gain over MiVeCC-{base} [%]")
            ax.set_title(f"{name[0].upper()}{name[1:]}: gain over MiVeCC-{base}, {grid} grid")
            ax.grid(alpha=0.3)
    legend: dict[str, Any] = {}  # one legend for all panels, below them (no data hidden)
    for ax in axes.flat:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(label, handle)
    fig.legend(list(legend.values()), list(legend), loc="lower center", ncol=3, fontsize=9)
    fig.suptitle(f"Paired by density and seed (dots: seeds){note}", fontsize=10)
    fig.tight_layout(rect=(0, 1.0 / height, 1, 1))
    fig.savefig(path, dpi=110)
    return True


def _label(scheme: str) -> str:
    """Legend name of a scheme."""
    if scheme == "signalized":
        return "signalized (fixed time + IDM)"
    if scheme == "coder":
        return "Coder (learned signals)"
    if scheme in CEILINGS:
        return f"ceiling {scheme}: {CEILINGS[scheme][1]} always +3 m/s^2"
    return f"MiVeCC-{scheme}"


def _paired_gains(rows: list[dict[str, Any]], grid: str, key: str = "avg_travel_velocity_mps",
                  base: str = "E", compared: Sequence[str] = ("EE", "EEC", "EE+3", "EEC+3"),
                  ) -> dict[str, dict[float, list[float]]]:
    """``scheme -> density -> [gain of each seed over the base scheme's run, %]`` in metric
    ``key``, for the ``compared`` schemes (pairs: same grid, density and seed; runs without
    the metric, e.g. an old CSV's, are left out)."""
    r, c = (int(x) for x in grid.split("x"))
    mine = [x for x in rows if (x["rows"], x["cols"]) == (r, c) and x.get(key) not in ("", None)]
    reference = {(x["density"], x["seed"]): float(x[key]) for x in mine if x["scheme"] == base}
    out: dict[str, dict[float, list[float]]] = {}
    for x in mine:
        pair = (x["density"], x["seed"])
        if x["scheme"] in compared and pair in reference:
            gain = improvement(float(x[key]), reference[pair])
            out.setdefault(x["scheme"], {}).setdefault(x["density"], []).append(gain)
    return out


#: Config fields the table's own options set (--grids, --densities, --schemes, --steps,
#: --model, --cloud-period): not accepted by --set.
OWN_FIELDS = {"rows": "--grids", "cols": "--grids", "density_vplh": "--densities",
              "scheme": "--schemes", "max_steps": "--steps", "model": "--model",
              "cloud_period": "--cloud-period"}


def config_overrides(items: Sequence[str], model: str,
                     own: dict[str, str] = OWN_FIELDS) -> dict[str, Any]:
    """``--set`` items as config overrides, checked now (one line and exit status 2 for a
    malformed item, an unknown field, a value out of range or a field one of the script's
    options sets: ``own`` maps those fields to their options)."""
    from mivecc_agents.cli import set_overrides

    overrides = set_overrides(items, own)
    from_overrides(model=model, **overrides)  # ConfigError naming the field and its range
    return overrides


def _grid_name(text: str) -> str:
    """Argument type: a grid ``ROWSxCOLS`` (checked by :func:`cli_args.grid`), kept as the
    name ``summarise`` and the file names use."""
    rows, cols = cli_args.grid(text)
    return f"{rows}x{cols}"


def main(argv: Sequence[str] | None = None) -> Path:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", nargs="+", type=_grid_name, default=["1x1", "3x3"])
    parser.add_argument("--densities", type=cli_args.density, nargs="+", default=list(DENSITIES))
    parser.add_argument("--schemes", nargs="+", default=list(DEFAULT_SCHEMES), choices=SCHEMES,
                        help="default: all but coder (the shipped Coder policy, grids of at "
                        "least 2x2; run it on its own and merge with --from-csv)")
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=cli_args.count(1), default=3000)
    parser.add_argument("--edge", default=None, help="edge checkpoint (default: shipped)")
    parser.add_argument("--cloud", default=None, help="cloud checkpoint (default: shipped)")
    parser.add_argument("--model", choices=("paper", "released"), default="paper",
                        help="env model; the shipped policies of that model are used")
    parser.add_argument("--cloud-period", type=cli_args.count(1), default=None,
                        help="steps between cloud decisions of EEC and EEC+3 (default: a "
                        "learned cloud's training period; EEC+3 every step)")
    parser.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", default=[],
                        help="other config fields for every run, e.g. cloud_graphs=per_lane "
                        "(`mivecc fields` lists them; not the ones the options above set)")
    parser.add_argument("--workers", type=cli_args.count(1), default=2)
    parser.add_argument("--per-env-calls", action="store_true",
                        help="call the learned policies once per environment, so that every "
                        "run equals its single run bit for bit whatever --seeds and "
                        "--densities (slower; default: one call on the stacked batch where a "
                        "check finds that exact)")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/paper_table"))
    parser.add_argument("--from-csv", type=cli_args.existing_file, nargs="+", default=None,
                        help="build the tables from earlier runs' paper_table.csv files "
                        "(e.g. one run per scheme) instead of running episodes; a run of a "
                        "later file replaces one of an earlier file with the same grid, "
                        "scheme, density and seed")
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    for option in ("grids", "seeds", "densities"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))
    if args.cloud_period is not None and not 1 <= args.cloud_period <= 1000:
        parser.error(f"--cloud-period: must be in [1, 1000] steps, got {args.cloud_period}")
    overrides = config_overrides(args.set_items, args.model)

    jobs = []  # one batch (all densities x seeds) per grid and scheme
    for grid in args.grids:
        r, c = (int(x) for x in grid.split("x"))
        for scheme in args.schemes:
            if scheme == "coder" and min(r, c) < 2:  # Coder needs 2x2 regions
                continue
            jobs.append((scheme, r, c, list(args.densities), args.steps, list(args.seeds),
                         args.edge, args.cloud, args.model, args.cloud_period, overrides,
                         args.per_env_calls))
    if args.from_csv:
        rows = merge_runs([read_runs_csv(path) for path in args.from_csv])
    else:
        rows = [row for batch in map_jobs(_run, jobs, args.workers, "batches") for row in batch]

    keys = list(dict.fromkeys(k for row in rows for k in row))
    with open(args.out / "paper_table.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys, restval="")
        writer.writeheader()
        writer.writerows(rows)
    command = "python benchmarks/paper_table.py " + " ".join(argv if argv is not None else
                                                              __import__("sys").argv[1:])
    parts = [f"Command: `{command.strip()}`", ""]
    if not args.from_csv:  # runs with learned policies reproduce bit for bit on this CPU kind
        machine = machine_info(with_torch=True)
        (args.out / "machine.json").write_text(json.dumps(machine, indent=2) + "\n")
        parts[1:1] = ["", f"Machine: {describe(machine)} (`machine.json`)."]
    else:  # where each CSV's runs were made, if its folder says so
        parts[1:1] = ["", *[f"Runs of `{path}` made on: {describe(json.loads(info.read_text()))}"
                            f" (`{info}`)." for path in args.from_csv
                            if (info := Path(path).parent / "machine.json").is_file()]]
    for grid in args.grids:
        text, mean = summarise(rows, grid)
        parts += [text, ""]
        extra = near_miss_table(rows, grid)
        if extra:
            parts += [extra, ""]
        note = "".join(f", {key}={value}" for key, value in overrides.items())
        plot(mean, grid, args.out / f"velocity_vs_density_{grid}.png", note)
        plot_gains(rows, grid, args.out / f"gains_{grid}.png", note)
    (args.out / "paper_table.md").write_text("\n".join(parts))
    print("\n".join(parts))
    return args.out


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
