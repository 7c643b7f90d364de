"""Speed of the MiVeCC simulator and environments, with Eclipse SUMO as the outside reference.

For every grid (``--grids``, default ``1x1 3x3``) and density (``--densities``, default
300 900 1500 2100 veh/lane/h) this measures, round-robin in one run:

(a) ``env <scheme>``: the full PettingZoo ``ParallelEnv.step`` (B = 1) with every observation
    its scheme uses, rewards and infos, for each scheme in ``--env-schemes`` (default E EEC;
    zero actions for every agent, the action dict built once);
(b) ``batched B=N``: ``mivecc_env.batched.BatchedMiVeCCEnv`` (scheme EEC: edge and cloud
    observations, rewards, zero actions) for N in ``--env-batches`` (default 1 16 64 256), when
    that module exists;
(c) ``core B=N``: the bare batched ``Simulator(cfg, batch_size=N).step()`` for N in
    ``--batches`` (default 1 16 64 256; scheme E, no coordinator actions);
(d) ``sumo <junction>``: when :func:`sumo_reference.sumo_available`, SUMO (libsumo) on the same
    grid and demand for each junction type in ``--sumo-junctions`` (default ``unregulated``,
    the like-for-like peer that never jams, plus ``right_before_left`` and ``traffic_light``
    (fixed time), which jam from about 900 veh/lane/h and are extra rows only).

Each measurement first runs ``--warmup`` untimed steps (the network fills; the batched env is
filled with bare core steps, then 20 untimed env steps), then times ``--steps`` steps with
``time.perf_counter``. With ``--repeats R`` every measurement of a grid and density runs R
times, round-robin over the engines, and the fastest run is kept (other processes on the
machine only ever slow a run down). Vehicle-steps are the simulator's own counter
(``Simulator.vehicle_steps``: vehicles moved per step, summed over the environments), read
before and after the timed loop, so counting costs nothing inside it; SUMO's count is a
``getIDCount()`` per step inside its timed loop (about 1 % of a step, see sumo_reference.py).
*queue/env* is the number of vehicles waiting to enter, per environment, at the end of the
timed steps (SUMO: its insertion backlog).

The headline ratio is vehicle-steps/s over SUMO-unregulated's (the engines carry different
numbers of vehicles, so steps/s alone flatters the lighter one); steps/s ratios and each
engine's vehicle count are printed beside it. Floors at 3x3 / 2100 veh/lane/h (measured,
never assumed): the full ParallelEnv step (scheme EEC) >= 1x, the batched env at B = 64 >= 5x
and the bare core at B = 64 >= 15x SUMO-unregulated's vehicle-steps/s.

Files: ``speed.csv`` (one row per measurement), ``speed.json`` (rows, ratios, floors and the
machine) and ``speed.md`` (the printed tables) under ``--out`` (default
``benchmarks/results/speed/``).

Usage::

    python benchmarks/speed.py                       # full run (long)
    python benchmarks/speed.py --grids 3x3 --densities 2100 --batches 64 --steps 500
    python benchmarks/speed.py --quick --out /tmp/speed   # seconds; for tests
"""

from __future__ import annotations

import argparse
import csv
import functools
import importlib.util
import json
import os
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

from mivecc_env import cli_args, mivecc_v0
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "speed"
PEER = "sumo unregulated"  # the like-for-like reference of every ratio
FLOOR_GRID = (3, 3)
FLOOR_DENSITY = 2100.0
#: (floor name, engine, required vehicle-steps/s ratio to SUMO-unregulated, description)
FLOORS = (
    ("env_b1", "env EEC", 1.0, "full ParallelEnv step (B=1, scheme EEC, all observations)"),
    ("batched_b64", "batched B=64", 5.0, "batched env (EEC observations) at B=64"),
    ("core_b64", "core B=64", 15.0, "bare core at B=64"),
)
CSV_FIELDS = (
    "grid", "rows", "cols", "density", "engine", "batch", "steps", "warmup", "elapsed_s",
    "steps_per_s", "env_steps_per_s", "mean_vehicles", "queue", "vehicle_steps_per_s",
)  # fmt: skip


def _load_sibling(name: str) -> ModuleType:
    """Import ``benchmarks/<name>.py`` (the benchmarks folder is not a package, and this
    script is also loaded by file path, without the folder on ``sys.path``)."""
    spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


sumo_reference = _load_sibling("sumo_reference")
machine_info = _load_sibling("machine_info").machine_info


def batched_available() -> bool:
    """Whether ``mivecc_env.batched.BatchedMiVeCCEnv`` exists in this checkout."""
    return importlib.util.find_spec("mivecc_env.batched") is not None


# ----------------------------------------------------------------------------------------------
# measurements
def _row(
    rows: int, cols: int, density: float, engine: str, batch: int, steps: int, warmup: int,
    elapsed: float, vehicle_steps: float, queue: float,
) -> dict[str, Any]:
    """One measurement as a flat record (the CSV row)."""
    return {
        "grid": f"{rows}x{cols}", "rows": rows, "cols": cols, "density": float(density),
        "engine": engine, "batch": batch, "steps": steps, "warmup": warmup,
        "elapsed_s": elapsed, "steps_per_s": steps / elapsed,
        "env_steps_per_s": batch * steps / elapsed,
        "mean_vehicles": vehicle_steps / (steps * batch), "queue": float(queue),
        "vehicle_steps_per_s": vehicle_steps / elapsed,
    }  # fmt: skip


class Engine(NamedTuple):
    """A warmed-up mivecc engine: ``step()`` advances it one step, ``sim`` counts its
    vehicle-steps (``Simulator.vehicle_steps``) and holds its entry queues."""

    name: str
    batch: int
    step: Callable[[], Any]
    sim: Simulator


def _timed(step: Callable[[], Any], sim: Simulator, steps: int) -> tuple[float, int]:
    """Wall seconds of ``steps`` calls of ``step`` and the vehicle-steps moved meanwhile."""
    before = int(sim.vehicle_steps.sum())
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    elapsed = time.perf_counter() - t0
    return elapsed, int(sim.vehicle_steps.sum()) - before


def env_engine(
    rows: int, cols: int, density: float, warmup: int, seed: int, scheme: str = "EEC",
    max_steps: int = 10_000_000,
) -> Engine:
    """(a) Full ``ParallelEnv.step`` (B = 1, zero actions, every observation of ``scheme``)."""
    env = mivecc_v0.parallel_env(
        rows=rows, cols=cols, density=density, scheme=scheme, max_steps=max_steps
    )
    env.reset(seed=seed)
    actions = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents}
    for _ in range(warmup):
        env.step(actions)
    return Engine(f"env {scheme}", 1, functools.partial(env.step, actions), env.sim)


def batched_engine(
    rows: int, cols: int, density: float, batch: int, warmup: int, seed: int
) -> Engine:
    """(b) ``BatchedMiVeCCEnv.step`` of ``batch`` environments, scheme EEC, zero actions."""
    from mivecc_env.batched import BatchedMiVeCCEnv

    env = BatchedMiVeCCEnv(batch_size=batch, rows=rows, cols=cols, density_vplh=float(density),
                           scheme="EEC", max_steps=10_000_000)
    env.reset(seed=seed)
    for _ in range(warmup):  # fill the network with bare core steps (cheap), then env steps
        env.sim.step()
    edge = np.zeros((batch, env.n_edge, env.k_edge))
    cloud = np.zeros((batch, env.k_cloud))
    step = functools.partial(env.step, edge, cloud)
    for _ in range(20):
        step()
    return Engine(f"batched B={batch}", batch, step, env.sim)


def core_engine(
    rows: int, cols: int, density: float, batch: int, warmup: int, seed: int
) -> Engine:
    """(c) Bare batched ``Simulator.step()`` of ``batch`` environments (scheme E)."""
    cfg = MiVeCCConfig(rows=rows, cols=cols, density_vplh=float(density), scheme="E")
    sim = Simulator(cfg, batch_size=batch, seed=seed)
    for _ in range(warmup):
        sim.step()
    return Engine(f"core B={batch}", batch, sim.step, sim)


def _measure(engine: Engine, rows: int, cols: int, density: float, steps: int,
             warmup: int) -> dict[str, Any]:
    elapsed, moved = _timed(engine.step, engine.sim, steps)
    return _row(rows, cols, density, engine.name, engine.batch, steps, warmup, elapsed, moved,
                float(engine.sim.queued.mean()))


def measure_env(
    rows: int, cols: int, density: float, steps: int, warmup: int, seed: int,
    scheme: str = "EEC",
) -> dict[str, Any]:
    """(a) Full ``ParallelEnv.step`` (B = 1, zero actions, every observation of ``scheme``),
    one episode of ``warmup + steps + 1`` steps."""
    engine = env_engine(rows, cols, density, warmup, seed, scheme, max_steps=warmup + steps + 1)
    return _measure(engine, rows, cols, density, steps, warmup)


def measure_batched(
    rows: int, cols: int, density: float, batch: int, steps: int, warmup: int, seed: int
) -> dict[str, Any]:
    """(b) ``BatchedMiVeCCEnv.step`` of ``batch`` environments, scheme EEC, zero actions."""
    engine = batched_engine(rows, cols, density, batch, warmup, seed)
    return _measure(engine, rows, cols, density, steps, warmup)


def measure_core(
    rows: int, cols: int, density: float, batch: int, steps: int, warmup: int, seed: int
) -> dict[str, Any]:
    """(c) Bare batched ``Simulator.step()`` of ``batch`` environments (scheme E)."""
    engine = core_engine(rows, cols, density, batch, warmup, seed)
    return _measure(engine, rows, cols, density, steps, warmup)


def measure_sumo(
    rows: int, cols: int, density: float, steps: int, warmup: int, seed: int,
    junction_type: str = "unregulated",
) -> dict[str, Any]:
    """(d) SUMO on the same grid and demand (see ``benchmarks/sumo_reference.py``)."""
    res = sumo_reference.run_sumo(rows, cols, density, steps, seed, warmup, junction_type)
    row = _row(rows, cols, density, f"sumo {junction_type}", 1, steps, warmup,
               res["elapsed_s"], res["mean_vehicles"] * steps, res["insertion_backlog"])
    row["vehicle_steps_per_s"] = res["vehicle_steps_per_s"]
    row["sumo"] = {k: res[k] for k in ("sumo_version", "junction_type", "teleports",
                                       "inserted", "insertion_backlog", "queue_start",
                                       "count_call_us")}
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
    """Per grid, density and engine: vehicle-steps/s and steps/s over SUMO-unregulated's."""
    out = []
    keys = sorted({(r["rows"], r["cols"], r["density"]) for r in results})
    for rows, cols, density in keys:
        group = [r for r in results
                 if (r["rows"], r["cols"], r["density"]) == (rows, cols, density)]
        peer = next((r for r in group if r["engine"] == PEER), None)
        if peer is None:
            continue
        for r in group:
            if r["engine"] == PEER:
                continue
            out.append({
                "grid": f"{rows}x{cols}", "rows": rows, "cols": cols, "density": density,
                "engine": r["engine"],
                "vehicle_steps_ratio": r["vehicle_steps_per_s"] / peer["vehicle_steps_per_s"],
                "steps_ratio": r["steps_per_s"] / peer["steps_per_s"],
                "vehicles": r["mean_vehicles"], "peer_vehicles": peer["mean_vehicles"],
                "queue": r["queue"], "peer_queue": peer["queue"],
            })  # fmt: skip
    return out


def floor_results(ratio_of: dict[str, float | None], measure: str) -> dict[str, Any]:
    """The brief's floors from ``ratio_of`` (engine -> its ratio to SUMO-unregulated at 3x3 /
    2100 veh/lane/h, None or absent when not measured); ``measure`` names the ratio."""
    result = {}
    for name, engine, need, text in FLOORS:
        value = ratio_of.get(engine)
        result[name] = {
            "description": f"{text}: {measure} >= {need:g}x SUMO-unregulated at 3x3, "
                           "2100 veh/lane/h",
            "engine": engine, "required_ratio": need, "measured_ratio": value,
            "met": None if value is None else bool(value >= need),
        }
    return result


def floors(ratio_rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The brief's floors at 3x3 / 2100 veh/lane/h: measured ratio and met / not met."""
    at = {r["engine"]: r["vehicle_steps_ratio"] for r in ratio_rows
          if (r["rows"], r["cols"], r["density"]) == (*FLOOR_GRID, FLOOR_DENSITY)}
    return floor_results(at, "vehicle-steps/s")


def floor_lines(floor: dict[str, Any]) -> list[str]:
    """One markdown line per floor: met, not met or not measured."""
    lines = []
    for f in floor.values():
        if f["met"] is None:
            verdict = (f"NOT MEASURED (needs 3x3, 2100 veh/lane/h, {f['engine']} and SUMO "
                       "unregulated in the run)")
        else:
            verdict = (f"{'MET' if f['met'] else 'NOT MET'} "
                       f"(measured {f['measured_ratio']:.2f}x, need {f['required_ratio']:g}x)")
        lines.append(f"- Floor: {f['description']}: **{verdict}**")
    return lines


def _num(x: float) -> str:
    return f"{x:,.0f}" if x >= 100 else f"{x:.1f}"


def markdown_tables(results: list[dict[str, Any]], ratio_rows: list[dict[str, Any]],
                    floor: dict[str, Any]) -> str:
    """The measurements, the ratios to SUMO-unregulated and the floors as markdown."""
    lines = [
        "| grid | density (veh/lane/h) | engine | steps/s | env-steps/s | vehicles/env "
        "| queue/env | vehicle-steps/s |",
        "|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            f"| {r['grid']} | {r['density']:.0f} | {r['engine']} | {_num(r['steps_per_s'])} "
            f"| {_num(r['env_steps_per_s'])} | {r['mean_vehicles']:.0f} | {r['queue']:.0f} "
            f"| {_num(r['vehicle_steps_per_s'])} |"
        )
    if ratio_rows:
        lines += [
            "",
            "Ratios to SUMO with `unregulated` junctions (same grid, demand and run):",
            "",
            "| grid | density | engine | **vehicle-steps/s ÷ SUMO-unreg.** | steps/s ÷ SUMO "
            "| vehicles/env (SUMO) | queue/env (SUMO) |",
            "|---|---:|---|---:|---:|---:|---:|",
        ]
        for r in ratio_rows:
            lines.append(
                f"| {r['grid']} | {r['density']:.0f} | {r['engine']} "
                f"| **{r['vehicle_steps_ratio']:.2f}** | {r['steps_ratio']:.2f} "
                f"| {r['vehicles']:.0f} ({r['peer_vehicles']:.0f}) "
                f"| {r['queue']:.0f} ({r['peer_queue']:.0f}) |"
            )
    lines += ["", *floor_lines(floor)]
    return "\n".join(lines)


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
def build_parser() -> argparse.ArgumentParser:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--grids", type=cli_args.grid, nargs="+", default=[(1, 1), (3, 3)],
                   help="grids as RxC (default 1x1 3x3)")
    p.add_argument("--densities", type=cli_args.density, nargs="+", default=[300, 900, 1500, 2100],
                   help="veh/lane/h (default 300 900 1500 2100)")
    p.add_argument("--batches", type=cli_args.count(1), nargs="+", default=[1, 16, 64, 256],
                   help="batch sizes of the bare core (default 1 16 64 256)")
    p.add_argument("--env-batches", type=cli_args.count(1), nargs="*", default=[1, 16, 64, 256],
                   help="batch sizes of the batched env (default 1 16 64 256; none: skip)")
    p.add_argument("--env-schemes", nargs="*", default=["E", "EEC"], choices=("E", "EE", "EEC"),
                   help="schemes of the full ParallelEnv step (default E EEC; none: skip)")
    p.add_argument("--sumo-junctions", nargs="*", choices=sumo_reference.JUNCTION_TYPES,
                   default=["unregulated", "right_before_left", "traffic_light"],
                   help="SUMO junction types (default unregulated right_before_left "
                   "traffic_light; unregulated is the peer of every ratio)")
    p.add_argument("--steps", type=cli_args.count(1), default=2000,
                   help="timed steps (default 2000)")
    p.add_argument("--warmup", type=cli_args.count(0), default=600,
                   help="untimed steps first (default 600)")
    p.add_argument("--repeats", type=cli_args.count(1), default=1,
                   help="repeat every measurement (SUMO too, round-robin), keep the fastest "
                   "(default 1)")
    p.add_argument("--seed", type=cli_args.seed, default=0)
    p.add_argument("--no-sumo", action="store_true", help="skip SUMO even if installed")
    p.add_argument("--no-env", action="store_true",
                   help="skip the ParallelEnv and batched env rows")
    p.add_argument("--quick", action="store_true",
                   help="tiny run for tests: 1x1, 900 veh/lane/h, core B=1,4, batched env B=2, "
                   "30 steps, 10 warm-up")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT,
                   help=f"output folder (default {DEFAULT_OUT.relative_to(HERE.parent)})")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the tables and write the files; returns the exit status."""
    args = build_parser().parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    if args.quick:
        args.grids, args.densities, args.batches = [(1, 1)], [900.0], [1, 4]
        args.env_batches = [2]
        args.steps, args.warmup, args.repeats = 30, 10, 1
    use_sumo = not args.no_sumo and sumo_reference.sumo_available() and bool(args.sumo_junctions)
    env_schemes = [] if args.no_env else args.env_schemes
    env_batches = [] if args.no_env or not batched_available() else args.env_batches

    # Per grid and density, the engines run one after the other and the repeats go round-robin
    # over them, so load from other processes hits mivecc and SUMO alike.
    groups: list[list[tuple[str, Callable[[], dict[str, Any]]]]] = []
    for rows, cols in args.grids:
        for density in args.densities:
            tag = f"{rows}x{cols} @{density:g}"
            kw = {"rows": rows, "cols": cols, "density": density, "steps": args.steps,
                  "warmup": args.warmup, "seed": args.seed}
            group: list[tuple[str, Callable[[], dict[str, Any]]]] = []
            for scheme in env_schemes:
                group.append((f"{tag} env {scheme}",
                              functools.partial(measure_env, scheme=scheme, **kw)))
            for b in env_batches:
                group.append((f"{tag} batched B={b}",
                              functools.partial(measure_batched, batch=b, **kw)))
            for b in args.batches:
                group.append((f"{tag} core B={b}", functools.partial(measure_core, batch=b, **kw)))
            if use_sumo:
                for junction in args.sumo_junctions:
                    group.append((f"{tag} sumo {junction}", functools.partial(
                        measure_sumo, junction_type=junction, **kw)))
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
    if not args.no_env and not batched_available():
        text += "\n\nBatched env not measured (mivecc_env.batched is not in this checkout)."
    given = sys.argv[1:] if argv is None else list(argv)
    command = shlex.join(["python", "benchmarks/speed.py", *given])
    document = {
        "command": command,
        "machine": machine_info(),
        "settings": {
            "grids": [f"{r}x{c}" for r, c in args.grids], "densities": args.densities,
            "batches": args.batches, "env_batches": env_batches, "env_schemes": env_schemes,
            "sumo_junctions": args.sumo_junctions if use_sumo else [],
            "steps": args.steps, "warmup": args.warmup,
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
    sys.exit(cli_args.run(main))
