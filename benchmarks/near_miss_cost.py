"""Per-step cost of the episode-metric hooks (near-miss measures and passing times).

Two simulators with the same seed step the same traffic; in one the hooks
(``Simulator.near_miss.record_step`` and ``Simulator.passing.record``) are replaced by no-ops.
After a warm-up that fills the network they step in turns (round-robin blocks, CPU time of this
process, so other load on a shared machine counts less), and the hooks alone are timed on the
final state, called as the step calls them (the per-environment clocks; with the compiled
kernels the passing times are recorded inside the move kernel, so only the near-miss hook runs
separately). Prints one line per batch size.

Usage:
    python benchmarks/near_miss_cost.py --batch 1 16 64 --density 2100
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence

from mivecc_env import cli_args
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim._numba import HAVE_NUMBA
from mivecc_env.sim.core import Simulator


def measure(batch: int, density: float, warmup: int, rounds: int, block: int) -> dict:
    """CPU time per step with and without the hooks, and of the hooks alone [ms]."""
    cfg = MiVeCCConfig(density_vplh=density)
    on = Simulator(cfg, batch_size=batch, seed=0)
    off = Simulator(cfg, batch_size=batch, seed=0)
    off.near_miss.record_step = lambda *a, **k: None
    off.passing.record = lambda *a, **k: None
    for sim in (on, off):
        for _ in range(warmup):
            sim.step()
    total = {"on": 0.0, "off": 0.0}
    for _ in range(rounds):
        for name, sim in (("on", on), ("off", off)):
            t = time.process_time()
            for _ in range(block):
                sim.step()
            total[name] += time.process_time() - t
    view = on.view
    flat = view.vehicle
    s, v = on.s.ravel()[flat], on.v.ravel()[flat]
    s_new = s + v * cfg.dt_s
    out = s_new >= on.network.lane_length[view.lane]
    t_enter = on.t_enter.ravel()[flat]
    clocks = on.env_time_s.copy()  # (B,) per-environment clocks, as the step passes them

    def hooks_once() -> None:
        """The hooks as ``Simulator.step`` runs them: with the compiled kernels the passing
        times are recorded inside the move kernel, so only the near-miss hook is separate."""
        on.near_miss.record_step(view, v, s_new, out, clocks, cfg.dt_s)
        if not HAVE_NUMBA:
            on.passing.record(view.env, view.lane, s, s_new, t_enter, clocks, cfg.dt_s)

    for _ in range(5):  # first calls compile / allocate: not timed
        hooks_once()
    reps = 200
    t = time.process_time()
    for _ in range(reps):
        hooks_once()
    hooks = (time.process_time() - t) / reps
    n = rounds * block
    return {"batch": batch, "vehicles": view.n_vehicles, "on_ms": 1e3 * total["on"] / n,
            "off_ms": 1e3 * total["off"] / n, "hooks_ms": 1e3 * hooks}


def main(argv: Sequence[str] | None = None) -> list[dict]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=cli_args.count(1), nargs="+", default=[1, 16])
    parser.add_argument("--density", type=cli_args.density, default=2100.0)
    parser.add_argument("--warmup", type=cli_args.count(0), default=1000,
                        help="steps before timing")
    parser.add_argument("--rounds", type=cli_args.count(1), default=20)
    parser.add_argument("--block", type=cli_args.count(1), default=25, help="steps per timed block")
    args = parser.parse_args(argv)
    results = []
    for b in args.batch:
        r = measure(b, args.density, args.warmup, args.rounds, args.block)
        results.append(r)
        print(f"B={b:3d} ({r['vehicles']} vehicles): step {r['off_ms']:.3f} ms without, "
              f"{r['on_ms']:.3f} ms with the hooks (x{r['on_ms'] / r['off_ms']:.2f}); "
              f"hooks alone {r['hooks_ms']:.3f} ms = "
              f"{100 * r['hooks_ms'] / r['off_ms']:.0f} % of a step without them")
    return results


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
