"""Two runs of the paper table side by side: which runs are bit-identical, how the gains moved.

Made for reruns on another machine (``docs/training.md``, "Reproducing these numbers on
another CPU"): the rules-only schemes are expected to be identical, runs driven by a learned
policy may not be (torch's CPU kernels round the networks' float32 outputs per CPU). For the
runs both CSVs hold (same grid, scheme, density and seed) this prints and writes

* per scheme, how many runs are identical in average travel velocity, released-style velocity
  and strict collision events, and how many in every column both CSVs have but the timings
  (:data:`TIMINGS`; a later CSV may have columns an earlier one lacks, such as config fields
  added since, and a cell empty in either, a run made before its column existed, is skipped),
  and the columns that differ with the number of runs differing in each;
* per grid and metric (average travel and released-style velocity), the gains EE vs E, EEC vs
  EE and EEC vs E [%] per density (of the means over seeds, as ``paper_table.md`` computes
  them) in either run, and the largest difference;
* the strict collision events of E, EE and EEC (those in both) per density (summed over
  seeds) in either run.

Usage (seconds; the committed session-21 rerun on an Intel Xeon against the published table):
    python benchmarks/table_diff.py docs/results/paper_table/paper_table.csv \\
        docs/results/reproducibility/paper_table_session21.csv \\
        --names "committed (AMD EPYC)" "session 21 (Intel Xeon)" \\
        --out docs/results/reproducibility/paper_table_diff_session21.md
"""

from __future__ import annotations

import csv
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from paper_table import RUN_KEY, improvement, read_runs_csv

from mivecc_env import cli_args

#: What must agree for two runs to count as identical (exact float equality).
COMPARED = ("avg_travel_velocity_mps", "released_velocity_mps", "collisions")
METRICS = {"avg_travel_velocity_mps": "average travel velocity",
           "released_velocity_mps": "released-style velocity"}
#: Columns left out of the every-column comparison: they time the run, not what it simulated.
TIMINGS = ("steps_per_s", "wall_s")
GAINS = (("EE", "E"), ("EEC", "EE"), ("EEC", "E"))
EVENT_SCHEMES = ("E", "EE", "EEC")


def _runs(rows: list[dict[str, Any]]) -> dict[tuple[Any, ...], dict[str, Any]]:
    return {tuple(r[k] for k in RUN_KEY): r for r in rows}


def _same(x: Any, y: Any) -> bool:
    """Exact equality, two NaNs counting as equal; a cell empty in either table is not
    compared (a merged table leaves the columns added after a run was made empty for it)."""
    if x == "" or y == "":
        return True
    return x == y or (isinstance(x, float) and isinstance(y, float) and x != x and y != y)


def identical_runs(a: list[dict[str, Any]], b: list[dict[str, Any]],
                   columns: Sequence[str] = COMPARED) -> dict[str, tuple[int, int]]:
    """``scheme -> (runs identical in ``columns``, runs in both)``."""
    ra, rb = _runs(a), _runs(b)
    out: dict[str, list[int]] = {}
    for key in sorted(set(ra) & set(rb), key=str):
        same = all(_same(ra[key].get(m), rb[key].get(m)) for m in columns)
        count = out.setdefault(str(ra[key]["scheme"]), [0, 0])
        count[0] += same
        count[1] += 1
    return {s: (c[0], c[1]) for s, c in out.items()}


def differing_columns(a: list[dict[str, Any]], b: list[dict[str, Any]],
                      columns: Sequence[str]) -> dict[str, int]:
    """``column -> runs in both that differ in it``, for the ``columns`` that differ anywhere
    (in ``columns``' order; empty cells skipped as in :func:`identical_runs`)."""
    ra, rb = _runs(a), _runs(b)
    keys = set(ra) & set(rb)
    counts = {c: sum(not _same(ra[k].get(c), rb[k].get(c)) for k in keys) for c in columns}
    return {c: n for c, n in counts.items() if n}


def shared_columns(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> list[str]:
    """The columns both tables have, but :data:`RUN_KEY` and :data:`TIMINGS`, in ``a``'s
    order."""
    theirs = set(b[0]) if b else set()
    return [c for c in (a[0] if a else ()) if c in theirs and c not in (*RUN_KEY, *TIMINGS)]


def _mean(rows: list[dict[str, Any]], scheme: str, grid: tuple[int, int], density: float,
          key: str) -> float:
    values = [float(r[key]) for r in rows if r["scheme"] == scheme
              and (r["rows"], r["cols"]) == grid and r["density"] == density
              and r.get(key) not in ("", None)]
    return float(np.mean(values)) if values else float("nan")


def gains(rows: list[dict[str, Any]], grid: tuple[int, int], densities: Sequence[float],
          key: str) -> dict[str, list[float]]:
    """``"A vs B" -> [gain of A's mean over B's mean per density, %]`` (NaN where missing)."""
    return {f"{x} vs {y}": [improvement(_mean(rows, x, grid, d, key), _mean(rows, y, grid, d, key))
                            for d in densities] for x, y in GAINS}


def events(rows: list[dict[str, Any]], scheme: str, grid: tuple[int, int],
           densities: Sequence[float]) -> list[int]:
    """Strict collision events of ``scheme`` per density, summed over seeds."""
    return [int(sum(float(r["collisions"]) for r in rows if r["scheme"] == scheme
                    and (r["rows"], r["cols"]) == grid and r["density"] == d))
            for d in densities]


def diff_markdown(a: list[dict[str, Any]], b: list[dict[str, Any]], names: Sequence[str]) -> str:
    """The comparison as markdown (see the module doc)."""
    na, nb = names
    ra, rb = _runs(a), _runs(b)
    common = [ra[k] for k in set(ra) & set(rb)]
    columns = shared_columns(a, b)
    every = identical_runs(a, b, columns)
    lines = ["Runs identical in average travel velocity, released-style velocity and strict "
             f"collision events, and in all {len(columns)} columns both tables have but the "
             f"timings ({', '.join(TIMINGS)}; cells empty in either skipped), {na} against {nb}:",
             "",
             "| scheme | identical / runs in both | identical in every column |",
             "|---|---|---|"]
    lines += [f"| {s} | {i} / {n} | {every[s][0]} / {n} |"
              for s, (i, n) in identical_runs(a, b).items()]
    differ = differing_columns(a, b, columns)
    if differ:
        lines += ["", "Columns that differ (runs in both that differ in each): "
                  + ", ".join(f"{c} {n}" for c, n in differ.items()) + "."]
    for grid in sorted({(r["rows"], r["cols"]) for r in common}):
        densities = sorted({r["density"] for r in common if (r["rows"], r["cols"]) == grid})
        head = "| | " + " | ".join(f"{d:g}" for d in densities) + " | largest difference |"
        rule = "|---" * (len(densities) + 2) + "|"
        for key, label in METRICS.items():
            ga, gb = gains(a, grid, densities, key), gains(b, grid, densities, key)
            lines += ["", f"{grid[0]}x{grid[1]}, gains in {label} [%]:", "", head, rule]
            for name in ga:
                if all(np.isnan(ga[name])) or all(np.isnan(gb[name])):
                    continue
                diff = np.nanmax(np.abs(np.subtract(ga[name], gb[name])))
                for who, g in ((na, ga[name]), (nb, gb[name])):
                    lines.append(f"| {name}, {who} | " + " | ".join(f"{x:+.2f}" for x in g)
                                 + f" | {diff:.2f} |")
        lines += ["", f"{grid[0]}x{grid[1]}, strict collision events summed over seeds:", "",
                  head.replace(" largest difference |", " total |"), rule]
        present = {str(r["scheme"]) for r in common if (r["rows"], r["cols"]) == grid}
        for scheme in (s for s in EVENT_SCHEMES if s in present):
            for who, rows in ((na, a), (nb, b)):
                ev = events(rows, scheme, grid, densities)
                lines.append(f"| {scheme}, {who} | " + " | ".join(map(str, ev))
                             + f" | {sum(ev)} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> str:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("a", type=Path, help="a paper_table.csv")
    parser.add_argument("b", type=Path, help="another paper_table.csv")
    parser.add_argument("--names", nargs=2, default=["A", "B"], metavar=("A", "B"),
                        help="what to call the two runs (e.g. their machines)")
    parser.add_argument("--out", type=Path, default=None, help="also write the markdown here")
    args = parser.parse_args(argv)
    tables = []
    for option, path in (("a", args.a), ("b", args.b)):
        try:
            rows = read_runs_csv(path)
        except OSError as exc:
            parser.error(f"{option}: cannot read {path}: {exc.strerror}")
        except (UnicodeDecodeError, csv.Error) as exc:
            parser.error(f"{option}: {path} is not a paper_table.csv ({exc})")
        missing = [k for k in (*RUN_KEY, *COMPARED) if rows and k not in rows[0]]
        if not rows or missing:
            parser.error(f"{option}: {path} is not a paper_table.csv (no runs, or no column "
                         f"{', '.join(missing)})")
        tables.append(rows)
    text = diff_markdown(*tables, args.names)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(f"Command: `python benchmarks/table_diff.py {args.a} {args.b} "
                            f"--names \"{args.names[0]}\" \"{args.names[1]}\" --out {args.out}`"
                            "\n\n" + text)
    print(text)
    return text


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
