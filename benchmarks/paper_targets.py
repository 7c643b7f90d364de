"""Issue 10's targets for the paper's table, judged from ``paper_table.py`` runs (3x3 grid).

Each ``--column`` is one set of runs: a label, then ``paper_table.csv`` files merged as
``paper_table.py --from-csv`` merges them (a later file's run replaces an earlier file's run of
the same grid, scheme, density and seed; e.g. the main table, then a constant cloud at the
learned cloud's period). Every target is judged on the densities the column has runs of, from
the means over its seeds, in the model's headline velocity (released model: the released-style
velocity; default model: the average travel velocity; ``--metric`` overrides). Gains are
compared as the tables print them, rounded to 0.01 points; the paper's values are
``paper_table.PAPER_3X3``. Strict collision events are the runs' ``collisions`` (any two
vehicles closer than 2 m), summed over the seeds.

Not judged here: whether the training curves rise and settle (``docs/training.md``).

Usage (the README's table; ``docs/results/paper_targets_released.md`` and
``docs/results/paper_targets_default.md`` add seeds 3-7 and 6000-step runs, with their commands):
    python benchmarks/paper_targets.py \\
        --column "released model" docs/results/paper_table_released/paper_table.csv \\
            docs/results/training/session15/pt_ceiling_eec3_p10.csv \\
        --column "default model" docs/results/paper_table/paper_table.csv \\
            docs/results/training/session17/pt_paper_ceiling_eec3_p10.csv
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from paper_table import PAPER_3X3, cell_runs, improvement, merge_runs, read_runs_csv

from mivecc_env import cli_args

#: The velocity metric of each model's headline table (CSV column, name).
METRICS = {"released": ("released_velocity_mps", "released-style velocity"),
           "paper": ("avg_travel_velocity_mps", "average travel velocity")}
#: Densities from which EE vs E must reach the paper's value [veh/lane/h].
EE_FROM_DENSITY = 1500
LEARNED = ("E", "EE", "EEC")
#: The targets, in the order of the table's rows.
ORDER = "EEC > EE > E at every density"
NO_EVENTS = "0 strict events in every cell (E, EE, EEC)"
EE_PAPER = f"EE vs E [%] at least the paper's from {EE_FROM_DENSITY} on"
EEC_POSITIVE = "EEC vs EE [%] positive at every density"
EEC_HALF = "EEC vs EE [%] at least half the paper's"
EDGE_CEILING = "the learned edge at or above the constant +3 edge (EE+3)"
CLOUD_CEILING = "the learned cloud at or above the constant +3 cloud (EEC+3)"


class Cell(NamedTuple):
    """One scheme at one density: the mean over its seeds."""

    velocity: float  # mean of the metric [m/s]
    events: int  # strict collision events, summed over the seeds
    cloud_period: int  # steps between cloud decisions


def cells(rows: list[dict[str, Any]], key: str) -> dict[tuple[str, int], Cell]:
    """``(scheme, density) -> Cell`` of the 3x3 runs (grouped by ``paper_table.cell_runs``)."""
    return {(scheme, int(density)): Cell(float(np.mean([float(r[key]) for r in runs])),
                                         int(sum(float(r["collisions"]) for r in runs)),
                                         int(runs[0].get("cloud_period") or 1))
            for (scheme, density), runs in cell_runs(rows, "3x3").items()}


def _gain(table: dict[tuple[str, int], Cell], a: str, b: str, density: int) -> float:
    """Gain of scheme ``a`` over ``b`` [%], rounded as the tables print it."""
    return round(improvement(table[(a, density)].velocity, table[(b, density)].velocity), 2)


def _densities(table: dict[tuple[str, int], Cell], schemes: Sequence[str]) -> list[int]:
    """The densities with runs of every one of ``schemes``."""
    found = {d for _, d in table}
    return sorted(d for d in found if all((s, d) in table for s in schemes))


def _at(densities: Sequence[int]) -> str:
    return " / ".join(str(d) for d in densities)


def _values(values: Sequence[float], signed: bool = True) -> str:
    return " / ".join(f"{v:+.2f}" if signed else f"{v:.2f}" for v in values)


def _judge(misses: list[int], detail: str, judged: Sequence[int] = ()) -> str:
    """"met" or "not met at <densities>" ("at any density" when every judged one misses)."""
    if not misses:
        verdict = "met"
    elif list(misses) == list(judged):
        verdict = "not met at any density"
    else:
        verdict = f"not met at {_at(misses)}"
    return f"{verdict}: {detail}" if detail else verdict


def judge(rows: list[dict[str, Any]], key: str) -> list[tuple[str, str]]:
    """``(target, verdict with its numbers)`` for every target this module judges, in the
    order of :data:`ORDER` ... :data:`CLOUD_CEILING`; "no data" where a scheme is missing."""
    table = cells(rows, key)
    verdicts: dict[str, str] = {}

    ds = _densities(table, LEARNED)
    if ds:
        misses = [d for d in ds if not table[("EEC", d)].velocity > table[("EE", d)].velocity
                  > table[("E", d)].velocity]
        verdicts[ORDER] = _judge(misses, f"{ds[0]}-{ds[-1]}")
        hits = []
        for s in LEARNED:
            where = [d for d in ds if table[(s, d)].events]
            if where:
                total = sum(table[(s, d)].events for d in where)
                hits.append(f"{s} {total} ({', '.join(map(str, where))})")
        verdicts[NO_EVENTS] = "met" if not hits else "not met: " + ", ".join(hits)

    ds = [d for d in _densities(table, ("E", "EE")) if d >= EE_FROM_DENSITY]
    if ds:
        gains = [_gain(table, "EE", "E", d) for d in ds]
        paper = [PAPER_3X3["EE vs E"][d] for d in ds]
        misses = [d for d, g, p in zip(ds, gains, paper, strict=True) if g < p]
        verdicts[EE_PAPER] = _judge(
            misses, f"{_values(gains)} against {_values(paper, False)} at {_at(ds)}")

    ds = _densities(table, ("EE", "EEC"))
    if ds:
        gains = [_gain(table, "EEC", "EE", d) for d in ds]
        half = [PAPER_3X3["EEC vs EE"][d] / 2 for d in ds]
        verdicts[EEC_POSITIVE] = _judge([d for d, g in zip(ds, gains, strict=True) if g <= 0],
                                        f"{min(gains):+.2f} to {max(gains):+.2f}")
        misses = [i for i, (g, h) in enumerate(zip(gains, half, strict=True)) if g < h]
        detail = ", ".join(f"{gains[i]:+.2f} against {half[i]:g} at {ds[i]}" for i in misses)
        verdicts[EEC_HALF] = _judge([ds[i] for i in misses], detail)

    ds = _densities(table, ("E", "EE", "EE+3"))
    if ds:
        ours = [improvement(table[("EE", d)].velocity, table[("E", d)].velocity) for d in ds]
        ceiling = [improvement(table[("EE+3", d)].velocity, table[("E", d)].velocity)
                   for d in ds]
        share = [100 * o / c for o, c in zip(ours, ceiling, strict=True) if round(c, 2) > 0]
        events = [table[("EE+3", d)].events for d in ds]
        detail = (f"EE vs E is {min(share):.0f}-{max(share):.0f} % of EE+3 vs E; EE+3 has "
                  f"{min(events)}-{max(events)} strict events per cell")
        misses = [d for d, o, c in zip(ds, ours, ceiling, strict=True)
                  if round(o, 2) < round(c, 2)]
        verdicts[EDGE_CEILING] = _judge(misses, detail, ds)

    ds = _densities(table, ("EE", "EEC", "EEC+3"))
    if ds:
        period = table[("EEC+3", ds[0])].cloud_period
        gaps = [round(_gain(table, "EEC", "EE", d) - _gain(table, "EEC+3", "EE", d), 2)
                for d in ds]
        detail = (f"EEC vs EE minus EEC+3 vs EE (every {period} step{'s' * (period > 1)}): "
                  f"{min(gaps):+.2f} to {max(gaps):+.2f} points")
        verdicts[CLOUD_CEILING] = _judge([d for d, g in zip(ds, gaps, strict=True) if g < 0],
                                         detail)

    needs = {ORDER: LEARNED, NO_EVENTS: LEARNED, EE_PAPER: ("E", "EE"),
             EEC_POSITIVE: ("EE", "EEC"), EEC_HALF: ("EE", "EEC"),
             EDGE_CEILING: ("E", "EE", "EE+3"), CLOUD_CEILING: ("EE", "EEC", "EEC+3")}
    return [(t, verdicts.get(t, f"no data (needs {', '.join(schemes)})"))
            for t, schemes in needs.items()]


def column_metric(rows: list[dict[str, Any]], metric: str, label: str) -> tuple[str, str]:
    """The (CSV column, name) a column is judged in: its model's headline metric by default."""
    if metric != "model":
        return next(m for m in METRICS.values() if m[0] == metric)
    models = {row.get("model") for row in rows}
    if len(models) != 1 or next(iter(models)) not in METRICS:
        raise cli_args.InputError(f"--column {label!r}: runs of one model expected (paper or "
                                  f"released), got {sorted(map(str, models))}")
    return METRICS[next(iter(models))]


def markdown(columns: Sequence[tuple[str, list[dict[str, Any]]]], metric: str = "model") -> str:
    """The targets table, one column per set of runs."""
    judged, heads = [], []
    for label, rows in columns:
        key, name = column_metric(rows, metric, label)
        seeds = sorted({int(r["seed"]) for r in rows if (r["rows"], r["cols"]) == (3, 3)})
        heads.append(f"{label} ({name}; seeds {', '.join(map(str, seeds))})")
        judged.append(dict(judge(rows, key)))
    targets = list(dict.fromkeys(t for j in judged for t in j))
    lines = ["| target | " + " | ".join(heads) + " |", "|---|" + "---|" * len(heads)]
    for target in targets:
        lines.append(f"| {target} | " + " | ".join(j.get(target, "") for j in judged) + " |")
    return "\n".join(lines)


#: Columns every run must have (the velocity metrics are checked when judged).
REQUIRED = ("rows", "cols", "scheme", "density", "seed", "collisions", "model",
            *(m[0] for m in METRICS.values()))


def _read(path: str, parser: cli_args.Parser) -> list[dict[str, Any]]:
    """The runs of one ``paper_table.csv``; a missing file or column is a usage error."""
    if not Path(path).is_file():
        parser.error(f"--column: no such file {path!r}")
    runs = read_runs_csv(Path(path))
    missing = [k for k in REQUIRED if not runs or k not in runs[0]]
    if missing:
        raise cli_args.InputError(f"--column: {path} is not a paper_table.csv with runs "
                                  f"(no column {missing[0]!r})")
    return runs


def main(argv: Sequence[str] | None = None) -> str:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--column", nargs="+", action="append", required=True,
                        metavar=("LABEL", "CSV"),
                        help="a label, then the paper_table.csv files of one set of runs")
    parser.add_argument("--metric", default="model",
                        choices=["model", *(m[0] for m in METRICS.values())],
                        help="velocity metric (default: the model's headline metric)")
    parser.add_argument("--out", type=Path, default=None,
                        help="also write the table, with its command, to this markdown file")
    args = parser.parse_args(argv)
    columns = []
    for label, *paths in args.column:
        if not paths:
            parser.error(f"--column {label!r}: needs at least one CSV after the label")
        columns.append((label, merge_runs([_read(path, parser) for path in paths])))
    text = markdown(columns, args.metric)
    print(text)
    if args.out is not None:
        cli_args.writable_dir("--out", args.out.parent)
        words = argv if argv is not None else sys.argv[1:]
        command = " ".join(f'"{w}"' if " " in w else w for w in words)
        args.out.write_text(f"Command: `python benchmarks/paper_targets.py {command}`\n\n"
                            f"{text}\n", encoding="utf-8")
    return text


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
