"""Speed against SUMO-unregulated in paired windows of equal wall time (robust to a noisy host).

``benchmarks/speed.py`` times each engine over a fixed number of steps and keeps the fastest
of ``--repeats`` round-robin runs. On a shared machine whose speed swings by a factor of two
within seconds, that favours the engine with the shortest timed window: 300 steps of SUMO last
about 0.2 s, 300 steps of the batched env at B = 64 about 2 s, so SUMO's fastest run catches a
quiet moment more often. This benchmark gives every engine the same exposure instead:

1. every engine is built and warmed up once (``--warmup`` steps, as in ``speed.py``) and stays
   alive: the full ParallelEnv step (``--env-schemes``), the batched env with EEC observations
   (``--env-batches``), the bare core (``--batches``) and SUMO with ``unregulated`` junctions
   (libsumo, one session);
2. ``--cycles`` times, each engine in turn steps for one window of ``--window-s`` wall seconds
   (whole steps, at least one; the engines' order rotates from cycle to cycle);
3. the **headline ratio** is an engine's fastest window over SUMO's fastest window (vehicle-
   steps/s): ``speed.py``'s estimator on windows of equal length, the nearest each engine came
   to an idle machine. Beside it: the ratio of the median windows, and each engine's
   vehicle-steps/s in a cycle over SUMO's in the same cycle (seconds apart, so both saw about
   the same machine), median and quartiles. SUMO slows down more than mivecc's engines when the
   host is busy, so these typical-load ratios come out higher than the headline.

Vehicle-steps are each engine's own count (``Simulator.vehicle_steps``; SUMO: ``getIDCount()``
after each step, inside the window). The floors of ``speed.py`` (3x3, 2100 veh/lane/h) are
judged on the headline ratio.

Files under ``--out`` (default ``benchmarks/results/speed_paired/``): ``speed_paired.csv`` (one
row per window), ``speed_paired.json`` (windows, summary, floors, machine) and
``speed_paired.md`` (the printed tables).

Usage::

    python benchmarks/speed_paired.py                       # 3x3, 2100, about 1 min
    python benchmarks/speed_paired.py --quick --out /tmp/p  # seconds; for tests
"""

from __future__ import annotations

import csv
import json
import os
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import speed  # a sibling: the script's folder is on sys.path

from mivecc_env import cli_args

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "speed_paired"
PEER = speed.PEER  # "sumo unregulated"
CSV_FIELDS = ("cycle", "engine", "batch", "steps", "elapsed_s", "vehicle_steps",
              "vehicle_steps_per_s", "mean_vehicles")
sumo_reference = speed.sumo_reference


def run_window(engine: speed.Engine, seconds: float) -> tuple[int, float, int]:
    """Step a mivecc engine until ``seconds`` of wall time have passed (at least one step):
    (steps, wall seconds, vehicle-steps)."""
    sim, step, clock = engine.sim, engine.step, time.perf_counter
    before = int(sim.vehicle_steps.sum())
    steps = 0
    t0 = clock()
    while True:
        step()
        steps += 1
        elapsed = clock() - t0
        if elapsed >= seconds:
            break
    return steps, elapsed, int(sim.vehicle_steps.sum()) - before


def summarise(windows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per engine: windows, median steps per window, median steps/s, median vehicles per
    environment, median vehicle-steps/s, and against SUMO-unregulated the per-cycle ratios'
    median and quartiles, the ratio of the fastest windows and of the median windows."""
    engines = list(dict.fromkeys(w["engine"] for w in windows))
    by = {e: [w for w in windows if w["engine"] == e] for e in engines}
    peer = {w["cycle"]: w["vehicle_steps_per_s"] for w in by.get(PEER, [])}
    peer_all = np.array(list(peer.values())) if peer else None
    out = []
    for e in engines:
        ws = by[e]
        vsps = np.array([w["vehicle_steps_per_s"] for w in ws])
        row: dict[str, Any] = {
            "engine": e, "batch": ws[0]["batch"], "windows": len(ws),
            "median_steps_per_window": float(np.median([w["steps"] for w in ws])),
            "median_steps_per_s": float(np.median([w["steps"] / w["elapsed_s"] for w in ws])),
            "mean_vehicles": float(np.median([w["mean_vehicles"] for w in ws])),
            "median_vehicle_steps_per_s": float(np.median(vsps)),
            "best_vehicle_steps_per_s": float(vsps.max()),
        }
        if peer_all is not None and e != PEER:
            per_cycle = np.array([w["vehicle_steps_per_s"] / peer[w["cycle"]] for w in ws
                                  if w["cycle"] in peer])
            q1, med, q3 = np.percentile(per_cycle, [25, 50, 75])
            row.update({
                "ratio_median": float(med), "ratio_q1": float(q1), "ratio_q3": float(q3),
                "ratio_min": float(per_cycle.min()), "ratio_max": float(per_cycle.max()),
                "ratio_of_best": float(vsps.max() / peer_all.max()),
                "ratio_of_medians": float(np.median(vsps) / np.median(peer_all)),
            })
        out.append(row)
    return out


def floors(summary: list[dict[str, Any]], grid: tuple[int, int], density: float
           ) -> dict[str, Any]:
    """``speed.py``'s floors, judged on the ratio of the fastest windows (only at 3x3 /
    2100)."""
    at_floor = (grid, float(density)) == (speed.FLOOR_GRID, speed.FLOOR_DENSITY)
    ratio = {r["engine"]: r.get("ratio_of_best") for r in summary} if at_floor else {}
    return speed.floor_results(ratio, "fastest-window vehicle-steps/s ratio")


def markdown(summary: list[dict[str, Any]], floor: dict[str, Any], settings: dict[str, Any]
             ) -> str:
    """The summary table and the floors as markdown."""
    lines = [
        f"{settings['grid']}, {settings['density']:g} veh/lane/h: {settings['cycles']} cycles, "
        f"one window of {settings['window_s']:g} s per engine per cycle.",
        "",
        "| engine | windows | steps/window (median) | vehicles/env | vehicle-steps/s (median) "
        "| **ratio to SUMO-unreg.: fastest windows** | median windows "
        "| per cycle: median [quartiles] (min-max) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in summary:
        if "ratio_median" in r:
            ratio = (f"**{r['ratio_of_best']:.2f}** | {r['ratio_of_medians']:.2f} "
                     f"| {r['ratio_median']:.2f} [{r['ratio_q1']:.2f}-{r['ratio_q3']:.2f}] "
                     f"({r['ratio_min']:.2f}-{r['ratio_max']:.2f})")
        else:
            ratio = "(the peer) | | "
        lines.append(
            f"| {r['engine']} | {r['windows']} | {r['median_steps_per_window']:.0f} "
            f"| {r['mean_vehicles']:.0f} | {r['median_vehicle_steps_per_s']:,.0f} | {ratio} |")
    lines += ["", *speed.floor_lines(floor)]
    return "\n".join(lines)


def build_parser() -> cli_args.Parser:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--grid", type=cli_args.grid, default=(3, 3), help="RxC (default 3x3)")
    p.add_argument("--density", type=cli_args.density, default=2100.0,
                   help="veh/lane/h (default 2100)")
    p.add_argument("--env-schemes", nargs="*", default=["EEC"], choices=("E", "EE", "EEC"),
                   help="schemes of the full ParallelEnv step (default EEC; none: skip)")
    p.add_argument("--env-batches", type=cli_args.count(1), nargs="*", default=[64],
                   help="batch sizes of the batched env, EEC observations (default 64)")
    p.add_argument("--batches", type=cli_args.count(1), nargs="*", default=[64],
                   help="batch sizes of the bare core (default 64)")
    p.add_argument("--cycles", type=cli_args.count(1), default=40,
                   help="windows per engine (default 40)")
    p.add_argument("--window-s", type=cli_args.number(0.001, 60.0), default=0.25,
                   help="wall seconds of one window (default 0.25)")
    p.add_argument("--warmup", type=cli_args.count(0), default=600,
                   help="untimed steps of every engine first (default 600)")
    p.add_argument("--seed", type=cli_args.seed, default=0)
    p.add_argument("--quick", action="store_true",
                   help="tiny run for tests: 1x1, 900 veh/lane/h, batched env B=2, core B=2, "
                   "3 cycles of 0.02 s, 100 warm-up steps")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT,
                   help=f"output folder (default {DEFAULT_OUT.relative_to(HERE.parent)})")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the tables and write the files; returns the exit status."""
    args = build_parser().parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    if args.quick:
        args.grid, args.density, args.env_batches, args.batches = (1, 1), 900.0, [2], [2]
        args.cycles, args.window_s, args.warmup = 3, 0.02, 100
    if not sumo_reference.sumo_available():
        raise cli_args.InputError(
            "SUMO is needed (the peer of every ratio): pip install mivecc[sumo]")
    rows, cols = args.grid
    kw = {"rows": rows, "cols": cols, "density": args.density, "warmup": args.warmup,
          "seed": args.seed}
    engines = [speed.env_engine(scheme=s, **kw) for s in args.env_schemes]
    engines += [speed.batched_engine(batch=b, **kw) for b in args.env_batches]
    engines += [speed.core_engine(batch=b, **kw) for b in args.batches]

    from tqdm.auto import tqdm

    windows: list[dict[str, Any]] = []
    load_before = os.getloadavg() if hasattr(os, "getloadavg") else None
    t_start = time.perf_counter()
    # SUMO's demand must outlast every step it can take: its windows at up to 20 000 steps/s
    # (the quick run's nearly empty 1x1 went past that on a 2-core Xeon: 200 000 there)
    max_rate = 200_000 if args.quick else 20_000
    horizon_s = ((args.warmup + args.cycles * (args.window_s * max_rate + 1))
                 * sumo_reference.STEP_LENGTH_S + 60.0)
    with sumo_reference.SumoSession(rows, cols, args.density, args.seed, "unregulated",
                                    horizon_s) as sumo:
        sumo.run_steps(args.warmup)
        names = [e.name for e in engines] + [PEER]
        total = args.cycles * len(names)
        with tqdm(total=total, unit="window", file=sys.stderr, disable=args.no_progress) as bar:
            for cycle in range(args.cycles):
                turn = cycle % len(names)
                for i in [*range(turn, len(names)), *range(turn)]:  # the order rotates
                    bar.set_description(names[i])
                    if i == len(engines):
                        steps, elapsed, moved = sumo.run_for(args.window_s)
                        batch = 1
                    else:
                        steps, elapsed, moved = run_window(engines[i], args.window_s)
                        batch = engines[i].batch
                    windows.append({
                        "cycle": cycle, "engine": names[i], "batch": batch, "steps": steps,
                        "elapsed_s": elapsed, "vehicle_steps": moved,
                        "vehicle_steps_per_s": moved / elapsed,
                        "mean_vehicles": moved / (steps * batch),
                    })
                    bar.update()
        sumo_stats = {**sumo.stats(), "insertion_backlog": sumo.backlog()}
    if sumo_stats["inserted"] == 0:
        raise RuntimeError("SUMO inserted no vehicle: the routes or the demand did not load")
    summary = summarise(windows)
    floor = floors(summary, args.grid, args.density)
    settings = {
        "grid": f"{rows}x{cols}", "density": args.density, "env_schemes": args.env_schemes,
        "env_batches": args.env_batches, "batches": args.batches, "cycles": args.cycles,
        "window_s": args.window_s, "warmup": args.warmup, "seed": args.seed,
    }  # fmt: skip
    text = markdown(summary, floor, settings)
    given = sys.argv[1:] if argv is None else list(argv)
    document = {
        "command": shlex.join(["python", "benchmarks/speed_paired.py", *given]),
        "machine": speed.machine_info(),
        "settings": settings,
        "wall_s": time.perf_counter() - t_start,
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg() if hasattr(os, "getloadavg") else None,
        "sumo": sumo_stats,
        "summary": summary,
        "floors": floor,
        "windows": windows,
    }  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    paths = [args.out / f"speed_paired.{ext}" for ext in ("csv", "json", "md")]
    with open(paths[0], "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(windows)
    paths[1].write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
    paths[2].write_text(f"Command: `{document['command']}`\n\n{text}\n", encoding="utf-8")
    print(text)
    print("\nwrote " + ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
