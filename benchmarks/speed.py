"""Speed of the MiVeCC simulator, with Eclipse SUMO on the same grid and demand as reference.

For every grid (``--grids``, default ``1x1 3x3``) and density (``--densities``, default
300 900 1500 2100 veh/lane/h) this measures

(a) ``env``: the full PettingZoo ``ParallelEnv.step`` with all observations, rewards and infos
    (B = 1, scheme E, zero actions for every agent, the action dict built once);
(b) ``core``: the bare batched ``Simulator(cfg, batch_size=B).step()`` for B in ``--batches``
    (default 1 16 64; scheme E, no coordinator actions);
(c) ``sumo``: when :func:`sumo_reference.sumo_available`, SUMO (libsumo) on the same grid and
    demand, in the same run (``run_sumo(rows, cols, density, steps, seed, warmup)``).

Each measurement first runs ``--warmup`` untimed steps (the network fills), then times
``--steps`` steps with ``time.perf_counter``. With ``--repeats R`` every measurement of a grid
and density runs R times, round-robin over the engines, and the fastest run is kept (other
processes on the machine only ever slow a run down). Vehicle-steps are the simulator's own counter
(``Simulator.vehicle_steps``: vehicles moved per step, summed over the environments), read
before and after the timed loop, so counting costs nothing inside it; SUMO's count is a
``getIDCount()`` per step inside its timed loop (about 1 % of a step, see sumo_reference.py).

Printed: a markdown table of all measurements, the ratios to SUMO per grid and density, and
the brief's two floors at 3x3 / 2100 veh/lane/h (measured, never assumed):

1. the full env step is at least as fast as SUMO's bare step (steps/s);
2. the batched core at B = 64 moves at least 10x SUMO's vehicle-steps/s.

Files: ``speed.csv`` (one row per measurement), ``speed.json`` (rows, ratios, floors and the
machine) and ``speed.md`` (the printed tables) under ``--out`` (default
``benchmarks/results/speed/``).

Usage::

    python benchmarks/speed.py                       # full run (several minutes)
    python benchmarks/speed.py --grids 3x3 --densities 2100 --batches 64 --steps 500
    python benchmarks/speed.py --quick --out /tmp/speed   # seconds; for tests
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import functools
import importlib.util
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from mivecc_env import mivecc_v0
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "speed"
FLOOR_GRID = (3, 3)
FLOOR_DENSITY = 2100.0
FLOOR_ENV_VS_SUMO_STEPS = 1.0
FLOOR_CORE64_VS_SUMO_VEH = 10.0
FLOOR_BATCH = 64
CSV_FIELDS = (
    "grid", "rows", "cols", "density", "engine", "batch", "steps", "warmup", "elapsed_s",
    "steps_per_s", "env_steps_per_s", "mean_vehicles", "vehicle_steps_per_s",
)  # fmt: skip


def _load_sumo_reference() -> ModuleType:
    """Import ``benchmarks/sumo_reference.py`` (the benchmarks folder is not a package)."""
    spec = importlib.util.spec_from_file_location("sumo_reference", HERE / "sumo_reference.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


sumo_reference = _load_sumo_reference()


# ----------------------------------------------------------------------------------------------
# measurements
def _row(
    rows: int, cols: int, density: float, engine: str, batch: int, steps: int, warmup: int,
    elapsed: float, vehicle_steps: float,
) -> dict[str, Any]:
    """One measurement as a flat record (the CSV row)."""
    return {
        "grid": f"{rows}x{cols}", "rows": rows, "cols": cols, "density": float(density),
        "engine": engine, "batch": batch, "steps": steps, "warmup": warmup,
        "elapsed_s": elapsed, "steps_per_s": steps / elapsed,
        "env_steps_per_s": batch * steps / elapsed,
        "mean_vehicles": vehicle_steps / (steps * batch),
        "vehicle_steps_per_s": vehicle_steps / elapsed,
    }  # fmt: skip


def measure_env(
    rows: int, cols: int, density: float, steps: int, warmup: int, seed: int
) -> dict[str, Any]:
    """(a) Full ``ParallelEnv.step`` (B = 1, scheme E, zero actions, all observations)."""
    env = mivecc_v0.parallel_env(
        rows=rows, cols=cols, density=density, scheme="E", max_steps=warmup + steps + 1
    )
    env.reset(seed=seed)
    actions = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents}
    step = env.step
    for _ in range(warmup):
        step(actions)
    before = int(env.sim.vehicle_steps.sum())
    t0 = time.perf_counter()
    for _ in range(steps):
        step(actions)
    elapsed = time.perf_counter() - t0
    moved = int(env.sim.vehicle_steps.sum()) - before
    env.close()
    return _row(rows, cols, density, "env", 1, steps, warmup, elapsed, moved)


def measure_core(
    rows: int, cols: int, density: float, batch: int, steps: int, warmup: int, seed: int
) -> dict[str, Any]:
    """(b) Bare batched ``Simulator.step()`` of ``batch`` environments (scheme E)."""
    cfg = MiVeCCConfig(rows=rows, cols=cols, density_vplh=float(density), scheme="E")
    sim = Simulator(cfg, batch_size=batch, seed=seed)
    step = sim.step
    for _ in range(warmup):
        step()
    before = int(sim.vehicle_steps.sum())
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    elapsed = time.perf_counter() - t0
    moved = int(sim.vehicle_steps.sum()) - before
    return _row(rows, cols, density, f"core B={batch}", batch, steps, warmup, elapsed, moved)


def measure_sumo(
    rows: int, cols: int, density: float, steps: int, warmup: int, seed: int
) -> dict[str, Any]:
    """(c) SUMO on the same grid and demand (see ``benchmarks/sumo_reference.py``)."""
    res = sumo_reference.run_sumo(rows, cols, density, steps, seed, warmup)
    row = _row(rows, cols, density, "sumo", 1, steps, warmup, res["elapsed_s"],
               res["mean_vehicles"] * steps)
    row["vehicle_steps_per_s"] = res["vehicle_steps_per_s"]
    row["sumo"] = {k: res[k] for k in ("sumo_version", "junction_type", "teleports",
                                       "inserted", "insertion_backlog", "count_call_us")}
    return row


def keep_fastest(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The fastest of repeated runs of one measurement (the least disturbed by other load)."""
    best = dict(min(runs, key=lambda r: r["elapsed_s"]))
    best["repeats"] = len(runs)
    best["steps_per_s_all"] = [r["steps_per_s"] for r in runs]
    return best


# ----------------------------------------------------------------------------------------------
# ratios, floors, reporting
def ratios(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per grid and density: env steps/s / SUMO steps/s, core B vehicle-steps/s / SUMO's."""
    out = []
    keys = sorted({(r["rows"], r["cols"], r["density"]) for r in results})
    for rows, cols, density in keys:
        group = {r["engine"]: r for r in results
                 if (r["rows"], r["cols"], r["density"]) == (rows, cols, density)}
        sumo = group.get("sumo")
        if sumo is None:
            continue
        entry: dict[str, Any] = {"grid": f"{rows}x{cols}", "rows": rows, "cols": cols,
                                 "density": density}
        if "env" in group:
            entry["env_vs_sumo_steps"] = group["env"]["steps_per_s"] / sumo["steps_per_s"]
        for engine, r in group.items():
            if engine.startswith("core B="):
                entry[f"core_b{r['batch']}_vs_sumo_vehicle_steps"] = (
                    r["vehicle_steps_per_s"] / sumo["vehicle_steps_per_s"]
                )
        out.append(entry)
    return out


def floors(ratio_rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The brief's two floors at 3x3 / 2100 veh/lane/h: measured ratio and met / not met."""
    at = [r for r in ratio_rows
          if (r["rows"], r["cols"], r["density"]) == (*FLOOR_GRID, FLOOR_DENSITY)]
    spec = (
        ("env_vs_sumo_steps", "env_vs_sumo_steps", FLOOR_ENV_VS_SUMO_STEPS,
         "full env step (B=1) steps/s >= SUMO steps/s at 3x3, 2100 veh/lane/h"),
        ("core_b64_vs_sumo_vehicle_steps", f"core_b{FLOOR_BATCH}_vs_sumo_vehicle_steps",
         FLOOR_CORE64_VS_SUMO_VEH,
         "batched core B=64 vehicle-steps/s >= 10x SUMO vehicle-steps/s at 3x3, 2100 veh/lane/h"),
    )
    result = {}
    for name, key, need, text in spec:
        value = at[0].get(key) if at else None
        result[name] = {
            "description": text, "required_ratio": need, "measured_ratio": value,
            "met": None if value is None else bool(value >= need),
        }
    return result


def _num(x: float) -> str:
    return f"{x:,.0f}" if x >= 100 else f"{x:.1f}"


def markdown_tables(results: list[dict[str, Any]], ratio_rows: list[dict[str, Any]],
                    floor: dict[str, Any]) -> str:
    """The measurements, the ratios and the floors as markdown."""
    lines = [
        "| grid | density (veh/lane/h) | engine | steps/s | env-steps/s | vehicles/env "
        "| vehicle-steps/s |",
        "|---|---:|---|---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            f"| {r['grid']} | {r['density']:.0f} | {r['engine']} | {_num(r['steps_per_s'])} "
            f"| {_num(r['env_steps_per_s'])} | {r['mean_vehicles']:.0f} "
            f"| {_num(r['vehicle_steps_per_s'])} |"
        )
    if ratio_rows:
        batches = sorted({int(k[6:].split("_")[0]) for r in ratio_rows for k in r
                          if k.startswith("core_b")})
        lines += [
            "",
            "| grid | density | env steps/s ÷ SUMO steps/s | "
            + " | ".join(f"core B={b} veh-steps/s ÷ SUMO" for b in batches) + " |",
            "|---|---:|---:|" + "---:|" * len(batches),
        ]
        for r in ratio_rows:
            env_ratio = r.get("env_vs_sumo_steps")
            cells = [f"{env_ratio:.2f}" if env_ratio is not None else "-"]
            for b in batches:
                v = r.get(f"core_b{b}_vs_sumo_vehicle_steps")
                cells.append(f"{v:.2f}" if v is not None else "-")
            lines.append(f"| {r['grid']} | {r['density']:.0f} | " + " | ".join(cells) + " |")
    lines.append("")
    for f in floor.values():
        if f["met"] is None:
            verdict = "NOT MEASURED (needs 3x3, 2100 veh/lane/h, B=64 and SUMO in the run)"
        else:
            verdict = (f"{'MET' if f['met'] else 'NOT MET'} "
                       f"(measured {f['measured_ratio']:.2f}x, need {f['required_ratio']:g}x)")
        lines.append(f"- Floor: {f['description']}: **{verdict}**")
    return "\n".join(lines)


def machine_info() -> dict[str, Any]:
    """Where and on what code the benchmark ran."""
    def git(*args: str) -> str | None:
        try:
            return subprocess.run(["git", *args], cwd=HERE, capture_output=True, text=True,
                                  check=True).stdout.strip()
        except (OSError, subprocess.CalledProcessError):
            return None

    cpu = platform.processor() or None
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            cpu = next((ln.split(":", 1)[1].strip() for ln in fh
                        if ln.startswith("model name")), cpu)
    except OSError:
        pass
    status = git("status", "--porcelain", "--untracked-files=no")
    return {
        "cpu": cpu, "cpu_count": os.cpu_count(),
        "affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "platform": platform.platform(), "python": platform.python_version(),
        "numpy": np.__version__, "git_commit": git("rev-parse", "HEAD"),
        "git_dirty": bool(status) if status is not None else None,
        "date_utc": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
    }  # fmt: skip


def write_outputs(out: Path, document: dict[str, Any], text: str) -> list[Path]:
    """``speed.csv``, ``speed.json`` and ``speed.md`` under ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "speed.csv", out / "speed.json", out / "speed.md"]
    with open(paths[0], "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(document["results"])
    paths[1].write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
    paths[2].write_text(f"Command: `{document['command']}`\n\n{text}\n", encoding="utf-8")
    return paths


# ----------------------------------------------------------------------------------------------
def _grid(text: str) -> tuple[int, int]:
    try:
        r, c = (int(x) for x in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"grid must look like 3x3, got {text!r}") from exc
    if r < 1 or c < 1:
        raise argparse.ArgumentTypeError(f"grid must have rows, cols >= 1, got {text!r}")
    return r, c


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--grids", type=_grid, nargs="+", default=[(1, 1), (3, 3)],
                   help="grids as RxC (default 1x1 3x3)")
    p.add_argument("--densities", type=float, nargs="+", default=[300, 900, 1500, 2100],
                   help="veh/lane/h (default 300 900 1500 2100)")
    p.add_argument("--batches", type=int, nargs="+", default=[1, 16, 64],
                   help="batch sizes of the bare core (default 1 16 64)")
    p.add_argument("--steps", type=int, default=2000, help="timed steps (default 2000)")
    p.add_argument("--warmup", type=int, default=600, help="untimed steps first (default 600)")
    p.add_argument("--repeats", type=int, default=1,
                   help="repeat every measurement (SUMO too, round-robin), keep the fastest "
                   "(default 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-sumo", action="store_true", help="skip SUMO even if installed")
    p.add_argument("--no-env", action="store_true", help="skip the full ParallelEnv step")
    p.add_argument("--quick", action="store_true",
                   help="tiny run for tests: 1x1, 900 veh/lane/h, B=1,4, 30 steps, 10 warm-up")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT,
                   help=f"output folder (default {DEFAULT_OUT.relative_to(HERE.parent)})")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the tables and write the files; returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.quick:
        args.grids, args.densities, args.batches = [(1, 1)], [900.0], [1, 4]
        args.steps, args.warmup, args.repeats = 30, 10, 1
    for name in ("steps", "repeats"):
        if getattr(args, name) < 1:
            print(f"speed.py: error: --{name} must be >= 1", file=sys.stderr)
            return 2
    if args.warmup < 0 or any(b < 1 for b in args.batches) or any(
        d <= 0 for d in args.densities
    ):
        print("speed.py: error: --warmup >= 0, --batches >= 1, --densities > 0", file=sys.stderr)
        return 2
    use_sumo = not args.no_sumo and sumo_reference.sumo_available()

    # Per grid and density, the engines run one after the other and the repeats go round-robin
    # over them, so load from other processes hits mivecc and SUMO alike.
    groups: list[list[tuple[str, Callable[[], dict[str, Any]]]]] = []
    for rows, cols in args.grids:
        for density in args.densities:
            tag = f"{rows}x{cols} @{density:g}"
            kw = {"rows": rows, "cols": cols, "density": density, "steps": args.steps,
                  "warmup": args.warmup, "seed": args.seed}
            group: list[tuple[str, Callable[[], dict[str, Any]]]] = []
            if not args.no_env:
                group.append((f"{tag} env", functools.partial(measure_env, **kw)))
            for b in args.batches:
                group.append((f"{tag} core B={b}", functools.partial(measure_core, batch=b, **kw)))
            if use_sumo:
                group.append((f"{tag} sumo", functools.partial(measure_sumo, **kw)))
            groups.append(group)

    from tqdm.auto import tqdm

    results = []
    load_before = os.getloadavg() if hasattr(os, "getloadavg") else None
    t_start = time.perf_counter()
    total = sum(len(g) for g in groups) * args.repeats
    with tqdm(total=total, unit="run", file=sys.stderr, disable=args.no_progress) as bar:
        for group in groups:
            runs: list[list[dict[str, Any]]] = [[] for _ in group]
            for _ in range(args.repeats):
                for (label, job), kept in zip(group, runs, strict=True):
                    bar.set_description(label)
                    kept.append(job())
                    bar.update()
            results.extend(keep_fastest(kept) for kept in runs)
    ratio_rows = ratios(results)
    floor = floors(ratio_rows)
    text = markdown_tables(results, ratio_rows, floor)
    if not use_sumo:
        text += "\n\nSUMO not run (" + ("--no-sumo" if args.no_sumo else "not installed") + ")."
    given = sys.argv[1:] if argv is None else list(argv)
    command = shlex.join(["python", "benchmarks/speed.py", *given])
    document = {
        "command": command,
        "machine": machine_info(),
        "settings": {
            "grids": [f"{r}x{c}" for r, c in args.grids], "densities": args.densities,
            "batches": args.batches, "steps": args.steps, "warmup": args.warmup,
            "repeats": args.repeats, "seed": args.seed, "sumo": use_sumo,
            "env": not args.no_env,
        },
        "wall_s": time.perf_counter() - t_start,
        # 1/5/15-minute load averages: other processes on the machine disturb the timings.
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg() if hasattr(os, "getloadavg") else None,
        "results": results,
        "ratios": ratio_rows,
        "floors": floor,
    }  # fmt: skip
    paths = write_outputs(args.out, document, text)
    print(text)
    print("\nwrote " + ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
