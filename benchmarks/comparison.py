"""The paper's comparison figures: every scheme against MiVeCC and the upper bound.

For each grid (single intersection 1x1, 3x3), density and seed, every scheme of
:data:`mivecc_agents.evaluation.SCHEMES` (MiVeCC E / EE / EEC with the shipped coordinators, the
signal controllers, PA-DQN and Coder with their shipped signal policies (Coder on grids of at
least 2x2 only), reservation, optimisation and CoMADDPG with its shipped vehicle policy) runs
one evaluation episode on the same seeded demand. Writes to ``--out``:

* ``comparison.csv``: one row per run (the JSON keys of ``mivecc evaluate``) and its ``source``
  (the CSV it was reused from, or ``simulated``),
* ``comparison_table.csv``: one row per grid, density and scheme: mean, sample standard
  deviation, min and max over the seeds of the average travel velocity, the collisions summed
  over the seeds, the upper bound and the share of it reached,
* ``comparison.md``: the same as tables (mean +- sd, collisions), the max-pressure vs
  fixed-time gain, throughput and backlog, the velocity without the entry wait and the share
  of arrivals that entered, MiVeCC-EEC vs Coder beside the paper's row, and the command that
  wrote it,
* ``comparison_<grid>.png``: average travel velocity (seed sd as error bars), throughput and
  collisions vs density.

``--comparator-entry slowed`` runs the comparators with ``comparator_entry="slowed"`` (they
enter at MiVeCC's clearance, slower into a short gap); runs are then reused from the CSVs only
where they were made with the same entry rule (MiVeCC's runs do not depend on it).
``--signal-keep-clear false`` runs the signal controllers without the keep-clear rule (on by
default since session 45); their runs are reused only where made with the same rule (a row
without the ``signal_keep_clear`` column was made without it).

Runs already in a CSV given with ``--from-csv`` are reused when grid, scheme, density, seed and
steps match, so only the missing runs are simulated; when several CSVs hold a run, the LAST one
given wins. Tables and figures are rebuilt from CSVs alone (seconds) with ``--tabulate-only``,
e.g. after the paper table is regenerated (its E / EE / EEC and fixed-time runs replace the
older ones)::

    python benchmarks/comparison.py --tabulate-only --from-csv \\
        docs/results/comparison/comparison.csv docs/results/paper_table/paper_table.csv

Usage (one command; progress on stderr):
    python benchmarks/comparison.py --grids 1x1 3x3 --seeds 0 1 2 --steps 3000 --workers 2 \\
        --from-csv docs/results/paper_table/paper_table.csv
"""

from __future__ import annotations

import argparse
import csv
import multiprocessing as mp
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from mivecc_agents.evaluation import COMPARATORS
from mivecc_env import cli_args
from mivecc_env.config import MiVeCCConfig

#: The comparators run under signals (their runs depend on ``signal_keep_clear``).
SIGNAL_SCHEMES = tuple(s for s, fields in COMPARATORS.items()
                       if fields.get("control") == "signalized")
#: The keep-clear rule of the runs made here (the config's default).
SIGNAL_KEEP_CLEAR: bool = MiVeCCConfig().signal_keep_clear
SCHEMES = ("E", "EE", "EEC", "fixed-time", "actuated", "max-pressure", "pa-dqn", "coder",
           "reservation", "optimisation", "comaddpg")
#: The paper's Table eff_imp_rate, row "MiVeCC-EEC vs. Coder" (3x3) [%], by density.
PAPER_EEC_VS_CODER = {300: 79.80, 600: 85.10, 900: 146.63, 1200: 283.32, 1500: 352.26,
                      1800: 419.48, 2100: 459.09}
DENSITIES = (300, 600, 900, 1200, 1500, 1800, 2100)
#: Older name of a scheme in earlier CSVs.
ALIASES = {"signalized": "fixed-time"}
#: Columns of ``comparison_table.csv``.
TABLE_KEYS = ("grid", "density", "scheme", "runs", "seeds", "steps", "velocity_mean_mps",
              "velocity_sd_mps", "velocity_min_mps", "velocity_max_mps", "collisions",
              "collided_vehicles", "upper_bound_mps", "share_of_upper_bound",
              "throughput_vph_mean", "backlog_mean", "velocity_no_wait_mean_mps",
              "entered_share", "source")


def _run(job: tuple[str, int, int, float, int, int, str, bool]) -> dict[str, Any]:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch: one thread per episode
    from mivecc_agents.evaluation import evaluate_scheme, shipped_comparator_policies

    scheme, rows, cols, density, steps, seed, entry, keep_clear = job
    if scheme in ("EE", "EEC"):
        from mivecc_agents.policies import pretrained_policies

        policies = pretrained_policies()
    else:
        policies = shipped_comparator_policies(scheme, rows, cols)
    out = evaluate_scheme(scheme, rows, cols, density, steps, seed, policies=policies,
                          progress=False, warn=False, comparator_entry=entry,
                          signal_keep_clear=keep_clear)
    out["source"] = "simulated"
    return out


def runs_on(scheme: str, rows: int, cols: int) -> bool:
    """Whether ``scheme`` runs on the grid (Coder needs 2x2 regions: not on 1x1)."""
    if scheme != "coder":
        return True
    from mivecc_agents.coder_settings import check_coder_grid
    from mivecc_env.config import ConfigError

    try:
        check_coder_grid(rows, cols)
    except ConfigError:
        return False
    return True


def _key(row: dict[str, Any]) -> tuple:
    scheme = ALIASES.get(str(row["scheme"]), str(row["scheme"]))
    return (scheme, int(float(row["rows"])), int(float(row["cols"])),
            int(float(row["density"])), int(float(row["seed"])), int(float(row["steps"])))


def made_with_keep_clear(row: dict[str, Any]) -> bool:
    """Whether a run's row was made with the signals' keep-clear rule: its
    ``signal_keep_clear`` column; a row without it was made before the column was recorded,
    when the rule was off by default."""
    return str(row.get("signal_keep_clear") or "False").strip().lower() in ("true", "1")


def load_rows(paths: Sequence[Path], model: str = "paper",
              comparator_entry: str = "stop_clearance",
              signal_keep_clear: bool = SIGNAL_KEEP_CLEAR) -> dict[tuple, dict[str, Any]]:
    """Earlier runs by (scheme, rows, cols, density, seed, steps); a later path wins.

    Only runs of the env ``model`` are kept (a row without a ``model`` column ran the default,
    ``"paper"``), of the comparators only those with ``comparator_entry`` (a row without
    the column ran the default, ``"stop_clearance"``; MiVeCC's runs do not depend on it), and
    of the signal controllers only those made with ``signal_keep_clear`` as given (the
    config's default; :func:`made_with_keep_clear`). A row without a ``source`` gets the path
    it was read from.
    """
    out: dict[tuple, dict[str, Any]] = {}
    for path in paths:
        with open(path, newline="", encoding="utf-8") as f:
            for row in csv.DictReader(f):
                row = dict(row)
                if (row.get("model") or "paper") != model:
                    continue
                entry = row.get("comparator_entry") or "stop_clearance"
                if row["scheme"] in COMPARATORS and entry != comparator_entry:
                    continue
                row["scheme"] = ALIASES.get(row["scheme"], row["scheme"])
                if (row["scheme"] in SIGNAL_SCHEMES
                        and made_with_keep_clear(row) != signal_keep_clear):
                    continue
                if not row.get("source"):
                    row["source"] = str(path)
                out[_key(row)] = row
    return out


def _cell_runs(rows: list[dict[str, Any]], grid: tuple[int, int], scheme: str,
               density: int) -> list[dict[str, Any]]:
    r, c = grid
    return [x for x in rows if x["scheme"] == scheme and int(float(x["rows"])) == r
            and int(float(x["cols"])) == c and int(float(x["density"])) == density]


def _number(row: dict[str, Any], key: str) -> float:
    """``row[key]`` as a float; NaN where the run has no such value (older CSVs)."""
    value = row.get(key)
    return float("nan") if value is None or value == "" else float(value)


def add_run_options(p: argparse.ArgumentParser) -> None:
    """``--grids`` (1x1 3x3), ``--densities`` (:data:`DENSITIES`), ``--seeds`` (0 1 2),
    ``--steps`` (3000) and ``--workers`` (1): the comparison's setting, for the scripts that
    rerun parts of it."""
    p.add_argument("--grids", nargs="+", type=cli_args.grid, default=[(1, 1), (3, 3)])
    p.add_argument("--densities", nargs="+", type=cli_args.whole_density,
                   default=list(DENSITIES))
    p.add_argument("--seeds", nargs="+", type=cli_args.seed, default=[0, 1, 2])
    p.add_argument("--steps", type=cli_args.count(1), default=3000)
    p.add_argument("--workers", type=cli_args.count(1), default=1)


def command_line(script: str, argv: Sequence[str] | None) -> str:
    """The command that ran ``benchmarks/<script>`` with ``argv`` (``sys.argv`` when None)."""
    return f"python benchmarks/{script} " + shlex.join(
        sys.argv[1:] if argv is None else list(argv))


def write_runs_and_tables(out: Path, stem: str, keys: Sequence[str],
                          runs: Sequence[dict[str, Any]], script: str,
                          argv: Sequence[str] | None, tables: str) -> None:
    """``<stem>.csv`` (every run, columns ``keys``) and ``<stem>.md`` (the command that wrote
    it, then ``tables``) in ``out``."""
    with open(out / f"{stem}.csv", "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(keys))
        writer.writeheader()
        writer.writerows(runs)
    (out / f"{stem}.md").write_text(
        f"Written by `{command_line(script, argv)}`.\n\n{tables}\n", encoding="utf-8")


def summarise(rows: list[dict[str, Any]], grids: Sequence[tuple[int, int]],
              schemes: Sequence[str], densities: Sequence[int]) -> list[dict[str, Any]]:
    """One row per (grid, density, scheme) with runs: :data:`TABLE_KEYS`.

    ``velocity_sd_mps`` is the sample standard deviation over the seeds (0 for one run).
    """
    out = []
    for g in grids:
        for d in densities:
            for s in schemes:
                runs = sorted(_cell_runs(rows, g, s, d), key=lambda x: int(float(x["seed"])))
                if not runs:
                    continue
                v = np.array([float(x["avg_travel_velocity_mps"]) for x in runs])
                bound = float(runs[0]["upper_bound_mps"])
                out.append({
                    "grid": f"{g[0]}x{g[1]}", "density": d, "scheme": s, "runs": len(runs),
                    "seeds": " ".join(str(int(float(x["seed"]))) for x in runs),
                    "steps": " ".join(sorted({str(int(float(x["steps"]))) for x in runs})),
                    "velocity_mean_mps": float(v.mean()),
                    "velocity_sd_mps": float(v.std(ddof=1)) if v.size > 1 else 0.0,
                    "velocity_min_mps": float(v.min()), "velocity_max_mps": float(v.max()),
                    "collisions": int(sum(float(x["collisions"]) for x in runs)),
                    "collided_vehicles": int(sum(float(x.get("collided_vehicles") or 0)
                                                 for x in runs)),
                    "upper_bound_mps": bound,
                    "share_of_upper_bound": float(v.mean() / bound) if bound > 0 else float("nan"),
                    "throughput_vph_mean": float(np.mean([float(x["throughput_vph"])
                                                          for x in runs])),
                    "backlog_mean": float(np.mean([_number(x, "backlog") for x in runs])),
                    "velocity_no_wait_mean_mps": float(np.mean([
                        _number(x, "avg_travel_velocity_no_wait_mps") for x in runs])),
                    "entered_share": float(np.mean([
                        1.0 - _number(x, "backlog") / _number(x, "arrived") for x in runs])),
                    "source": " ".join(sorted({str(x.get("source") or "") for x in runs})),
                })
    return out


def gain(rows: list[dict[str, Any]], grid: tuple[int, int], density: int,
         scheme: str = "max-pressure", baseline: str = "fixed-time") -> float | None:
    """Relative velocity gain [%] of ``scheme`` over ``baseline`` on the seeds both have."""
    by_seed = {s: {int(float(x["seed"])): float(x["avg_travel_velocity_mps"])
                   for x in _cell_runs(rows, grid, s, density)} for s in (scheme, baseline)}
    common = sorted(set(by_seed[scheme]) & set(by_seed[baseline]))
    if not common:
        return None
    new = float(np.mean([by_seed[scheme][k] for k in common]))
    old = float(np.mean([by_seed[baseline][k] for k in common]))
    return 100.0 * (new / old - 1.0) if old > 0 else None


def markdown(rows: list[dict[str, Any]], grids: Sequence[tuple[int, int]],
             schemes: Sequence[str], densities: Sequence[int],
             comparator_entry: str = "stop_clearance") -> str:
    """Tables of mean +- sd velocity (and collisions) per grid, density and scheme."""
    table = {(t["grid"], t["density"], t["scheme"]): t
             for t in summarise(rows, grids, schemes, densities)}
    lines = []
    for g in grids:
        name = f"{g[0]}x{g[1]}"
        sub = [t for k, t in table.items() if k[0] == name]
        if not sub:
            continue
        on_grid = [s for s in schemes if any(t["scheme"] == s for t in sub)]
        seeds = sorted({int(s) for t in sub for s in t["seeds"].split()})
        steps = {t["scheme"]: t["steps"] for t in sub}
        short = sorted({f"{s} {v}" for s, v in steps.items()
                        if v != max(steps.values(), key=lambda x: int(x.split()[0]))})
        lines += [f"### {name}: average travel velocity [m/s], mean +- sample sd over seeds "
                  f"{seeds}; collision events summed over the seeds in brackets; "
                  "n = runs where fewer than the seeds", ""]
        if short:
            lines += [f"Steps per run: {max(steps.values())}, except {', '.join(short)}.", ""]
        lines.append("| density | " + " | ".join(on_grid) + " | upper bound | max-pressure vs "
                     "fixed-time (same seeds) |")
        lines.append("|---" * (len(on_grid) + 3) + "|")
        for d in densities:
            cells, bound = [str(d)], ""
            for s in on_grid:
                t = table.get((name, d, s))
                if t is None:
                    cells.append("")
                    continue
                few = f" n={t['runs']}" if t["runs"] < len(seeds) else ""
                cells.append(f"{t['velocity_mean_mps']:.2f} +- {t['velocity_sd_mps']:.2f} "
                             f"({t['collisions']}){few}")
                bound = f"{t['upper_bound_mps']:.2f}"
            gp = gain(rows, g, d)
            lines.append("| " + " | ".join([*cells, bound, "" if gp is None else f"{gp:+.1f} %"])
                         + " |")
        for title, cell in _EXTRA_TABLES:
            lines += ["", *_scheme_table(
                f"### {name}: {title.format(entry=ENTRY_RULES[comparator_entry])}",
                {(d, s): cell(t) for (grid_name, d, s), t in table.items() if grid_name == name},
                on_grid, densities)]
        lines += _eec_vs_coder(rows, g, densities)
        lines.append("")
    return "\n".join(lines)


def _eec_vs_coder(rows: list[dict[str, Any]], grid: tuple[int, int],
                  densities: Sequence[int]) -> list[str]:
    """The paper's headline row on this grid (where both ran): MiVeCC-EEC's velocity gain
    over Coder [%] on the same seeds, beside the paper's (3x3) and EEC over fixed-time."""
    gains = {d: (gain(rows, grid, d, "EEC", "coder"), gain(rows, grid, d, "EEC", "fixed-time"))
             for d in densities}
    if all(g is None for g, _ in gains.values()):
        return []
    paper = grid == (3, 3)
    lines = ["", f"### {grid[0]}x{grid[1]}: MiVeCC-EEC vs Coder, average travel velocity gain "
             "[%] on the same seeds (the paper's Table eff_imp_rate row" +
             (")" if paper else ", reported for 3x3)"), "",
             "| density | EEC vs Coder | paper (3x3) | EEC vs fixed-time |", "|---|---|---|---|"]
    for d, (vs_coder, vs_fixed) in gains.items():
        cells = ["" if x is None else f"{x:+.1f} %" for x in (vs_coder, vs_fixed)]
        ref = f"+{PAPER_EEC_VS_CODER[d]:.1f} %" if d in PAPER_EEC_VS_CODER else ""
        lines.append(f"| {d} | {cells[0]} | {ref} | {cells[1]} |")
    return lines


#: The tables after the velocity table of each grid: (title, text of a cell from its
#: ``summarise`` row).
_EXTRA_TABLES: tuple[tuple[str, Any], ...] = (
    ("throughput [veh/h] / entry backlog at the end [veh], means over the seeds (the velocity "
     "counts only vehicles that left the network: a scheme that serves less traffic is not "
     "better for a higher velocity)",
     lambda t: f"{t['throughput_vph_mean']:.0f} / {t['backlog_mean']:.0f}"),
    ("average travel velocity without the entry wait [m/s] / share of the arrivals that "
     "entered the network, means over the seeds ({entry})",
     lambda t: f"{t['velocity_no_wait_mean_mps']:.2f} / {100 * t['entered_share']:.0f} %"),
)
#: How the comparators' vehicles entered, by ``comparator_entry`` (in the tables' titles).
ENTRY_RULES = {
    "stop_clearance": "the comparators enter a vehicle only with room to stop behind a standing "
                      "one, docs/comparators.md",
    "slowed": "comparator_entry=slowed: the comparators enter a vehicle at MiVeCC's clearance, "
              "slower into a short gap, docs/comparators.md",
}


def _scheme_table(title: str, cells: dict[tuple[int, str], str], schemes: Sequence[str],
                  densities: Sequence[int]) -> list[str]:
    """A markdown table under ``title``: one row per density, one column per scheme, the
    ``cells[(density, scheme)]`` text (empty where a cell has no runs)."""
    lines = [title, "", "| density | " + " | ".join(schemes) + " |",
             "|---" * (len(schemes) + 1) + "|"]
    for d in densities:
        row = [str(d), *(cells.get((d, s), "") for s in schemes)]
        lines.append("| " + " | ".join(row) + " |")
    return lines


def plot(rows: list[dict[str, Any]], grid: tuple[int, int], schemes: Sequence[str],
         densities: Sequence[int], path: Path, comparator_entry: str = "stop_clearance"
         ) -> None:
    """Velocity (seed sd as error bars), the same zoomed on the schemes within 10 % of the upper
    bound at every density (MiVeCC's and CoMADDPG's differences are tenths of a m/s),
    throughput and collisions vs density, with the upper bound (a figure of runs with
    ``comparator_entry="slowed"`` says so above the panels)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = summarise(rows, [grid], schemes, densities)
    if not table:
        return
    r, c = grid
    fig, (ax_v, ax_z, ax_t, ax_c) = plt.subplots(1, 4, figsize=(22, 4.8))
    bound = table[0]["upper_bound_mps"]
    present = [s for s in schemes if any(t["scheme"] == s for t in table)]
    for i, s in enumerate(present):
        cells = [t for t in table if t["scheme"] == s]
        if cells:
            # ten colours: a scheme past the tenth repeats one with another marker and dashes
            style = {"color": f"C{i % 10}", "marker": "os"[i // 10 % 2],
                     "ls": "-" if i < 10 else "--", "label": f"MiVeCC-{s}"
                     if s in ("E", "EE", "EEC") else s}
            xs = [t["density"] for t in cells]
            ax_v.errorbar(xs, [t["velocity_mean_mps"] for t in cells],
                          yerr=[t["velocity_sd_mps"] for t in cells], capsize=3, **style)
            ax_c.plot(xs, [t["collisions"] for t in cells], **style)
            ax_t.plot(xs, [t["throughput_vph_mean"] for t in cells], **style)
            if min(t["velocity_mean_mps"] for t in cells) >= 0.9 * bound:
                ax_z.errorbar(xs, [t["velocity_mean_mps"] for t in cells],
                              yerr=[t["velocity_sd_mps"] for t in cells], capsize=3, **style)
    for ax in (ax_v, ax_z):
        ax.axhline(bound, color="k", ls="--", label="upper bound")
        ax.set_xlabel("density [veh/lane/h]")
        ax.set_ylabel("average travel velocity [m/s]")
    seeds = sorted({int(x) for t in table for x in t["seeds"].split()})
    ax_v.set_title(f"{r}x{c}: average travel velocity (mean +- sd, seeds {seeds})")
    ax_v.legend(fontsize=7, loc="lower left", ncol=2)
    ax_z.set_title(f"{r}x{c}: zoom on the schemes within 10 % of the upper bound")
    ax_z.legend(fontsize=7, loc="lower left")
    ax_t.set_xlabel("density [veh/lane/h]")
    ax_t.set_ylabel("throughput [veh/h] (vehicles that left the network)")
    ax_t.set_title(f"{r}x{c}: throughput (mean over seeds)")
    ax_t.legend(fontsize=7, loc="upper left", ncol=2)
    ax_c.set_xlabel("density [veh/lane/h]")
    ax_c.set_ylabel("collision events (sum over seeds)")
    ax_c.set_yscale("symlog")
    ax_c.set_title(f"{r}x{c}: collisions (strict: any two vehicles < 2 m)")
    if comparator_entry != "stop_clearance":
        fig.suptitle(f"comparators with comparator_entry={comparator_entry}: they enter at "
                     "MiVeCC's clearance, slower into a short gap")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--grids", nargs="+", type=cli_args.grid, default=[(1, 1), (3, 3)])
    p.add_argument("--schemes", nargs="+", default=list(SCHEMES), choices=SCHEMES)
    p.add_argument("--densities", nargs="+", type=cli_args.whole_density, default=list(DENSITIES))
    p.add_argument("--seeds", nargs="+", type=cli_args.seed, default=[0, 1, 2])
    p.add_argument("--steps", type=cli_args.count(1), default=3000,
                   help="env steps of 0.1 s per run")
    p.add_argument("--steps-for", nargs="+", default=[], metavar="SCHEME=STEPS",
                   help="fewer steps for a slow scheme, e.g. optimisation=1000")
    p.add_argument("--workers", type=cli_args.count(1), default=1,
                   help="processes (1: in this process)")
    p.add_argument("--from-csv", nargs="+", type=cli_args.existing_file, default=[],
                   help="reuse matching runs of earlier CSVs (the last CSV holding a run wins)")
    p.add_argument("--tabulate-only", action="store_true",
                   help="simulate nothing: tables and figures of the runs found in --from-csv")
    p.add_argument("--model", default="paper", choices=("paper",),
                   help="env model of the runs reused from --from-csv (others are ignored); "
                   "the comparators run the default model")
    p.add_argument("--comparator-entry", default="stop_clearance",
                   choices=("stop_clearance", "slowed"),
                   help="the comparators' entry rule (config comparator_entry; "
                   "docs/comparators.md: slowed enters at MiVeCC's clearance, slower where the "
                   "lane's last vehicle is close; default stop_clearance)")
    p.add_argument("--signal-keep-clear", default=str(SIGNAL_KEEP_CLEAR).lower(),
                   choices=("true", "false"),
                   help="the signal controllers' keep-clear rule (config signal_keep_clear; "
                   "docs/comparators.md, \"Keeping the box clear\"; default "
                   f"{str(SIGNAL_KEEP_CLEAR).lower()}); runs reused from --from-csv must "
                   "have been made with the same rule")
    p.add_argument("--out", type=Path, default=Path("docs/results/comparison"))
    args = p.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    for option in ("grids", "seeds", "densities"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))
    return args


def _steps_for(items: Sequence[str], schemes: Sequence[str]) -> dict[str, int]:
    out = {}
    for item in items:
        name, _, value = item.partition("=")
        if name not in schemes or not value.isdigit() or int(value) < 1:
            raise cli_args.InputError(
                f"--steps-for: expected SCHEME=STEPS with SCHEME in {list(schemes)} and STEPS "
                f"an integer >= 1, got {item!r}")
        out[name] = int(value)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    grids = args.grids
    steps_for = _steps_for(args.steps_for, SCHEMES)
    keep_clear = args.signal_keep_clear == "true"
    known = load_rows(args.from_csv, args.model, args.comparator_entry, keep_clear)
    jobs, rows = [], []
    for (r, c) in grids:
        for d in args.densities:
            for s in args.schemes:
                if not runs_on(s, r, c):
                    continue
                for seed in args.seeds:
                    steps = steps_for.get(s, args.steps)
                    key = (s, r, c, d, seed, steps)
                    if key in known:
                        rows.append(known[key])
                    else:
                        jobs.append((s, r, c, float(d), steps, seed, args.comparator_entry,
                                     keep_clear))
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
    table = summarise(rows, grids, args.schemes, args.densities)
    _write_csv(table, args.out / "comparison_table.csv", keys=TABLE_KEYS, sort=False)
    command = command_line("comparison.py", argv)
    md = markdown(rows, grids, args.schemes, args.densities, args.comparator_entry)
    header = (f"Written by `{command}` from {len(rows)} runs (sources: "
              f"{', '.join(sorted({str(r.get('source') or '') for r in rows})) or 'none'}; "
              "`simulated` = run by that command or an earlier one whose CSV it reused)"
              f"{'' if keep_clear else '; the signal controllers without the keep-clear rule'}"
              ".\n")
    (args.out / "comparison.md").write_text(header + "\n" + md + "\n", encoding="utf-8")
    for g in grids:
        plot(rows, g, args.schemes, args.densities, args.out / f"comparison_{g[0]}x{g[1]}.png",
             args.comparator_entry)
    print(md)
    return 0


def _write_csv(rows: list[dict[str, Any]], path: Path, keys: Sequence[str] | None = None,
               sort: bool = True) -> None:
    if keys is None:
        keys = []
        for r in rows:
            keys += [k for k in r if k not in keys]
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(keys))
        w.writeheader()
        for r in sorted(rows, key=_key) if sort else rows:
            w.writerow(r)


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
