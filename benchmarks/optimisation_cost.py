"""Cost of the optimisation scheme's MILP (``control="optimisation"``) by window size.

Runs ``Simulator(control="optimisation")`` for ``--steps`` steps at each window size
(``optimisation_max_vehicles``) and reports the wall time of the run and of the schedules
(:func:`mivecc_env.sim.optimisation.schedule_milp`, timed by wrapping it) by number of
vehicles scheduled, the MILPs solved per schedule (a second one without the upper bounds when
the first is infeasible), and the collision events. Wall times, so only indicative on a
shared machine: say its load next to them.

Usage:
    python benchmarks/optimisation_cost.py --windows 6 8 10 12 --density 2100 --steps 600
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from mivecc_env import cli_args
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import optimisation as op
from mivecc_env.sim.core import Simulator


def measure(window: int, rows: int, density: float, steps: int, seed: int) -> dict[str, Any]:
    """One run; the schedules' wall times by size and the MILPs per schedule."""
    sizes: dict[int, list[float]] = {}
    milps = [0]
    schedule, solve = op.schedule_milp, op._solve

    def timed_schedule(*args: Any, **kw: Any) -> np.ndarray:
        t0 = time.perf_counter()
        out = schedule(*args, **kw)
        sizes.setdefault(int(args[0].size), []).append(time.perf_counter() - t0)
        return out

    def counted_solve(*args: Any, **kw: Any) -> Any:
        milps[0] += 1
        return solve(*args, **kw)

    op.schedule_milp, op._solve = timed_schedule, counted_solve
    try:
        cfg = MiVeCCConfig(rows=rows, cols=rows, control="optimisation", density_vplh=density,
                           optimisation_max_vehicles=window)
        sim = Simulator(cfg, seed=seed)
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step()
        wall = time.perf_counter() - t0
    finally:
        op.schedule_milp, op._solve = schedule, solve
    solves = sum(len(v) for v in sizes.values())
    at_window = np.array(sizes.get(window, [np.nan]))
    return {"window": window, "wall_s": wall, "schedules": solves,
            "milps_per_schedule": milps[0] / max(solves, 1),
            "schedule_s_total": float(sum(sum(v) for v in sizes.values())),
            "full_window_mean_ms": 1e3 * float(np.mean(at_window)),
            "full_window_max_ms": 1e3 * float(np.max(at_window)),
            "collisions": int(sim.collision_events[0]), "exited": int(sim.exited[0])}


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--windows", nargs="+", type=cli_args.count(1), default=[6, 8, 10, 12])
    p.add_argument("--rows", type=cli_args.count(1), default=1, help="grid rows = cols")
    p.add_argument("--density", type=cli_args.density, default=2100.0, help="veh/lane/h")
    p.add_argument("--steps", type=cli_args.count(1), default=600)
    p.add_argument("--seed", type=cli_args.seed, default=0)
    args = p.parse_args(argv)
    measure(args.windows[0], args.rows, args.density, 100, args.seed)  # imports, compiling
    print(f"load average {os.getloadavg()[0]:.1f}; {args.rows}x{args.rows}, {args.density:g} "
          f"veh/lane/h, seed {args.seed}, {args.steps} steps")
    out = []
    for w in args.windows:
        r = measure(w, args.rows, args.density, args.steps, args.seed)
        out.append(r)
        print(f"window {w:2d}: run {r['wall_s']:.1f} s, {r['schedules']} schedules "
              f"({r['schedule_s_total']:.1f} s, {r['milps_per_schedule']:.2f} MILPs each), "
              f"full window {r['full_window_mean_ms']:.0f} ms mean / "
              f"{r['full_window_max_ms']:.0f} ms max, {r['collisions']} collision events",
              flush=True)
    return out


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
