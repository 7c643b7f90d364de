"""Summary of every committed ``speed.py`` run: one row per run, then the spread per machine.

Reads ``session<N>/speed_run<R>.json`` under ``--runs`` (default
``docs/results/performance``; each file is the ``speed.json`` one ``benchmarks/speed.py`` run
wrote) and prints, per run, SUMO-unregulated's fastest round and the three floors' ratios
(vehicle-steps/s over SUMO-unregulated's, as ``speed.py`` computes them within its run), then,
per CPU, the range and median of each ratio and how many runs met each floor. The runs differ in
nothing but the host's load: read the spread as the measurement's uncertainty.

Then the same for every committed ``benchmarks/speed_paired.py`` run
(``session<N>/speed_paired_run<R>.json``): per run the floors' ratios of the fastest windows
(its headline) and the median per-cycle ratios with their quartiles, per CPU their ranges and
how many runs met each floor by either estimator.

Writes the same markdown to ``--out`` (default ``<runs>/summary.md``).

Usage::

    python benchmarks/speed_summary.py
    python benchmarks/speed_summary.py --runs docs/results/performance --out /tmp/summary.md
"""

from __future__ import annotations

import json
import re
import statistics
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from mivecc_env import cli_args

HERE = Path(__file__).resolve().parent
DEFAULT_RUNS = HERE.parent / "docs" / "results" / "performance"
PEER = "sumo unregulated"
#: (floor key in ``speed.json``, column title of the per-run table)
FLOOR_COLUMNS = (
    ("env_b1", "env EEC, B=1 (floor 1x)"),
    ("batched_b64", "batched env, B=64 (floor 5x)"),
    ("core_b64", "core, B=64 (floor 15x)"),
)
#: (engine in ``speed.json``'s ratios, row title of the per-CPU table)
ENGINE_ROWS = (
    ("env EEC", "full PettingZoo step, scheme EEC, B=1"),
    ("batched B=1", "batched env, EEC observations, B=1"),
    ("batched B=64", "batched env, EEC observations, B=64"),
    ("core B=1", "bare core, B=1"),
    ("core B=64", "bare core, B=64"),
)


class SummaryError(cli_args.InputError):
    """A run file that is unreadable or lacks a field the summary needs."""


def machine_label(machine: dict[str, Any]) -> str:
    """CPU name and its widest vector instruction set, e.g. ``AMD EPYC, AVX-512``."""
    flags = set(machine.get("cpu_flags", ()))
    isa = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return f"{machine.get('cpu', 'unknown CPU')}, {isa}"


def _load(runs_dir: Path, name: str, script: str,
          parse: Callable[[dict[str, Any]], dict[str, Any]]) -> list[dict[str, Any]]:
    """One record per ``session<N>/<name><R>.json`` under ``runs_dir`` (ordered by session then
    run): the run's session, number, commit, date and CPU, plus ``parse(doc)``'s fields; a file
    that does not parse is a :class:`SummaryError` naming it and ``script``."""
    pattern = re.compile(rf"session(\d+)/{name}(\d+)\.json$")
    records = []
    for path in sorted(runs_dir.glob(f"session*/{name}*.json")):
        match = pattern.search(path.as_posix())
        if match is None:
            continue
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            records.append({
                "session": int(match.group(1)), "run": int(match.group(2)),
                "commit": doc["machine"]["git_commit"][:7],
                "date_utc": doc["machine"]["date_utc"][:16].replace("T", " "),
                "machine": machine_label(doc["machine"]),
                **parse(doc),
            })
        except (OSError, ValueError, KeyError, StopIteration, TypeError) as err:
            raise SummaryError(
                f"{path}: not a {script} result ({type(err).__name__}: {err})") from None
    records.sort(key=lambda r: (r["session"], r["run"]))
    return records


def _speed_fields(doc: dict[str, Any]) -> dict[str, Any]:
    peer = next(r for r in doc["results"] if r["engine"] == PEER)
    floors = doc["floors"]
    return {
        "sumo_steps_per_s": float(peer["steps_per_s"]),
        **{key: float(floors[key]["measured_ratio"]) for key, _ in FLOOR_COLUMNS},
        "ratios": {r["engine"]: float(r["vehicle_steps_ratio"]) for r in doc["ratios"]},
        "required": {floors[key]["engine"]: float(floors[key]["required_ratio"])
                     for key, _ in FLOOR_COLUMNS},
        **{f"{key}_required": float(floors[key]["required_ratio"]) for key, _ in FLOOR_COLUMNS},
    }


def load_runs(runs_dir: Path) -> list[dict[str, Any]]:
    """One record per ``speed.py`` run file, ordered by session then run."""
    return _load(runs_dir, "speed_run", "speed.py", _speed_fields)


def _met(record: dict[str, Any], key: str) -> bool:
    return record[key] >= record[f"{key}_required"]


def markdown(records: list[dict[str, Any]]) -> str:
    """The per-run table and the per-machine spread, as markdown."""
    head = ["session", "run", "commit", "date (UTC)", "CPU", "SUMO-unreg. steps/s",
            *(title for _, title in FLOOR_COLUMNS)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * 5 + "---:|" * (len(head) - 5)]
    for r in records:
        ratios = [f"{r[key]:.2f}" + ("" if _met(r, key) else " (missed)")
                  for key, _ in FLOOR_COLUMNS]
        lines.append(f"| {r['session']} | {r['run']} | `{r['commit']}` | {r['date_utc']} | "
                     f"{r['machine']} | {r['sumo_steps_per_s']:,.0f} | " + " | ".join(ratios)
                     + " |")
    for machine in dict.fromkeys(r["machine"] for r in records):
        group = [r for r in records if r["machine"] == machine]
        sessions = sorted({r["session"] for r in group})
        span = (f"session {sessions[0]}" if len(sessions) == 1
                else f"sessions {sessions[0]}-{sessions[-1]}")
        lines += ["", f"{machine}: {len(group)} runs, {span}; "
                  "each ratio's range and median over the runs, and the runs that met its "
                  "floor:", "", "| engine | range | median | floor |", "|---|---:|---:|---|"]
        for engine, title in ENGINE_ROWS:
            values = [r["ratios"][engine] for r in group if engine in r["ratios"]]
            if not values:
                continue
            floor = "-"
            need = group[0]["required"].get(engine)
            if need is not None:
                met = sum(x >= need for x in values)
                floor = f"{need:g}x: met in {met} of {len(values)}"
            lines.append(f"| {title} | {min(values):.2f}-{max(values):.2f}x | "
                         f"{statistics.median(values):.2f}x | {floor} |")
    return "\n".join(lines) + "\n"


def _paired_fields(doc: dict[str, Any]) -> dict[str, Any]:
    rows = {r["engine"]: r for r in doc["summary"]}

    def floor(f: dict[str, Any]) -> dict[str, Any]:
        row = rows[f["engine"]]
        return {"engine": f["engine"], "required": float(f["required_ratio"]),
                "median": float(row["ratio_median"]), "q1": float(row["ratio_q1"]),
                "q3": float(row["ratio_q3"]), "best": float(row["ratio_of_best"])}

    return {"sumo_steps_per_s": float(rows[PEER]["median_steps_per_s"]),
            "floors": {key: floor(f) for key, f in doc["floors"].items()}}


def load_paired_runs(runs_dir: Path) -> list[dict[str, Any]]:
    """One record per ``speed_paired.py`` run file, ordered by session then run."""
    return _load(runs_dir, "speed_paired_run", "speed_paired.py", _paired_fields)


def paired_markdown(records: list[dict[str, Any]]) -> str:
    """The paired-window runs: per run, then per CPU, as markdown."""
    head = ["session", "run", "commit", "date (UTC)", "CPU", "SUMO-unreg. steps/s (median)",
            *(title for _, title in FLOOR_COLUMNS)]
    lines = ["Paired windows (`benchmarks/speed_paired.py`): per floor the ratio of the engines' "
             "fastest windows (the headline), then the median per-cycle ratio [quartiles].", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * 5 + "---:|" * (len(head) - 5)]
    for r in records:
        cells = [f"{f['best']:.2f}" + ("" if f["best"] >= f["required"] else " (missed)")
                 + f"; {f['median']:.2f} [{f['q1']:.2f}-{f['q3']:.2f}]"
                 for f in (r["floors"][key] for key, _ in FLOOR_COLUMNS)]
        lines.append(f"| {r['session']} | {r['run']} | `{r['commit']}` | {r['date_utc']} | "
                     f"{r['machine']} | {r['sumo_steps_per_s']:,.0f} | " + " | ".join(cells)
                     + " |")
    for machine in dict.fromkeys(r["machine"] for r in records):
        group = [r for r in records if r["machine"] == machine]
        lines += ["", f"{machine}: {len(group)} paired runs; per floor the range and median "
                  "over the runs of each estimator, and the runs that met the floor by it:", "",
                  "| floor | fastest windows: range, median | met | "
                  "median per-cycle ratio: range, median | met |", "|---|---:|---|---:|---|"]
        for key, title in FLOOR_COLUMNS:
            need = group[0]["floors"][key]["required"]
            cells = []
            for est in ("best", "median"):
                values = [r["floors"][key][est] for r in group]
                met = sum(x >= need for x in values)
                cells += [f"{min(values):.2f}-{max(values):.2f}x, "
                          f"{statistics.median(values):.2f}x", f"{met} of {len(values)}"]
            lines.append(f"| {title} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def summary_text(runs_dir: Path) -> str:
    """The whole summary of the committed runs under ``runs_dir`` (``speed.py``'s, then the
    paired ones if any)."""
    records = load_runs(runs_dir)
    if not records:
        raise SummaryError(f"--runs {runs_dir}: no session<N>/speed_run<R>.json files")
    paired = load_paired_runs(runs_dir)
    return markdown(records) + ("\n" + paired_markdown(paired) if paired else "")


def main(argv: Sequence[str] | None = None) -> int:
    """Print the summary and write it to ``--out``; returns the exit status."""
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=Path, default=DEFAULT_RUNS,
                   help="folder of session<N>/speed_run<R>.json files "
                   "(default docs/results/performance)")
    p.add_argument("--out", type=Path, default=None,
                   help="markdown file to write (default <runs>/summary.md)")
    args = p.parse_args(argv)
    text = summary_text(args.runs)
    out = args.out if args.out is not None else args.runs / "summary.md"
    cli_args.writable_dir("--out", out.parent)
    out.write_text(text, encoding="utf-8")
    print(text)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
