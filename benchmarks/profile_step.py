"""Where the time of one step goes: cProfile split of the bare core and the full env step.

Runs ``--warmup`` untimed steps, then ``--steps`` steps under ``cProfile`` and prints, for
each phase, its cumulative time per step and its share of the step (phases nest: the core's
phases are parts of ``Simulator.step``, which is part of the env step). cProfile adds its own
overhead per Python call (most to the many small numpy calls), so read the shares, not the
absolute times; ``benchmarks/speed.py`` gives the speeds.

Usage::

    python benchmarks/profile_step.py --grid 3x3 --density 2100 --batch 64
    python benchmarks/profile_step.py --grid 3x3 --density 2100 --env EEC   # ParallelEnv, B=1
    python benchmarks/profile_step.py --batched-env 64 --timer cpu   # BatchedMiVeCCEnv, EEC obs

``--timer cpu`` charges each call its process CPU time instead of wall time: on a machine
shared with other jobs the shares then depend much less on the load.
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import time
from collections.abc import Callable

import numpy as np

from mivecc_env import cli_args

#: (label, module file suffix, function name) of the phases reported.
PHASES = (
    ("env step (all)", "parallel_env.py", "step"),
    ("batched env step (all)", "batched.py", "step"),
    ("  core: Simulator.step", "core.py", "step"),
    ("    virtual-lane view (build_view)", "virtual_lane.py", "build_view"),
    ("      view kernel (points, sort, neighbours)", "view_kernel.py", "_build"),
    ("    safety values (_compute_safety)", "core.py", "_compute_safety"),
    ("      safety_value (logs, tanh)", "safety.py", "safety_value"),
    ("    accelerations (_unsignalized_accel)", "core.py", "_unsignalized_accel"),
    ("    signalized accelerations", "signals.py", "signalized_accel"),
    ("    motion (bounded_motion)", "end_node.py", "bounded_motion"),
    ("    exits (_record_exits)", "core.py", "_record_exits"),
    ("    collisions (_remove_collisions)", "core.py", "_remove_collisions"),
    ("    near-miss measures (record_step)", "near_miss.py", "record_step"),
    ("    passing times (record)", "passing.py", "record"),
    ("    entries (_enter_vehicles)", "core.py", "_enter_vehicles"),
    ("      arrivals.advance", "arrivals.py", "advance"),
    ("  observations and rewards (_observe_and_pack)", "batched.py", "_observe_and_pack"),
    ("    edge state graphs", "state_graph.py", "edge_graphs"),
    ("      edge decisions (select_edge_decisions)", "state_graph.py", "select_edge_decisions"),
    ("    cloud state graph", "state_graph.py", "cloud_graphs"),
    ("      cloud decisions (select_cloud_di)", "graph_kernel.py",
     "select_cloud_di"),
    ("    graph fill kernel (both graphs)", "graph_kernel.py", "_build"),
    ("    density indicator", "virtual_lane.py", "density_indicator"),
    ("    reward terms", "batched.py", "_reward_terms"),
    ("  actions (ParallelEnv _columns)", "parallel_env.py", "_columns"),
    ("  per-slot commands (_commands)", "batched.py", "_commands"),
    ("  observation dict (ParallelEnv)", "parallel_env.py", "_observations"),
    ("  infos (ParallelEnv)", "parallel_env.py", "_infos"),
    ("    episode summary", "metrics.py", "episode_summary"),
)


def split(stats: pstats.Stats, steps: int) -> list[tuple[str, float]]:
    """(label, cumulative microseconds per step) of every phase that ran."""
    table = stats.stats  # type: ignore[attr-defined]
    out = []
    for label, suffix, name in PHASES:
        total = sum(v[3] for (file, _line, fn), v in table.items()
                    if fn == name and file.endswith(suffix))
        if total > 0:
            out.append((label, total / steps * 1e6))
    return out


def main(argv: list[str] | None = None) -> int:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--grid", type=cli_args.grid, default=(3, 3), help="ROWSxCOLS (default 3x3)")
    p.add_argument("--density", type=cli_args.density, default=2100.0)
    p.add_argument("--batch", type=cli_args.count(1), default=1,
                   help="core batch size (ignored with --env)")
    p.add_argument("--env", choices=("E", "EE", "EEC"), default=None,
                   help="profile the full ParallelEnv step (B=1) of this scheme instead")
    p.add_argument("--batched-env", type=cli_args.count(1), default=None, metavar="B",
                   help="profile BatchedMiVeCCEnv.step (scheme EEC, EEC observations) at B")
    p.add_argument("--timer", choices=("wall", "cpu"), default="wall",
                   help="cProfile clock: wall time or this process's CPU time")
    p.add_argument("--steps", type=cli_args.count(1), default=300)
    p.add_argument("--warmup", type=cli_args.count(0), default=600)
    a = p.parse_args(argv)
    rows, cols = a.grid
    step: Callable[[], object]
    if a.batched_env:
        from mivecc_env.batched import BatchedMiVeCCEnv

        benv = BatchedMiVeCCEnv(batch_size=a.batched_env, rows=rows, cols=cols,
                                density=a.density, scheme="EEC",
                                max_steps=a.warmup + a.steps + 30)
        benv.reset(seed=0)
        for _ in range(a.warmup):  # fill the network with bare core steps (as speed.py does)
            benv.sim.step()
        a.warmup = 20
        step = benv.step
        what = f"BatchedMiVeCCEnv.step scheme EEC, B={a.batched_env}"
    elif a.env:
        from mivecc_env import mivecc_v0

        env = mivecc_v0.parallel_env(rows=rows, cols=cols, density=a.density, scheme=a.env,
                                     max_steps=a.warmup + a.steps + 10)
        env.reset(seed=0)
        act = {x: np.zeros(env.action_space(x).shape, np.float32) for x in env.possible_agents}

        def step() -> object:
            return env.step(act)

        what = f"ParallelEnv.step scheme {a.env}, B=1"
    else:
        from mivecc_env.config import MiVeCCConfig
        from mivecc_env.sim.core import Simulator

        sim = Simulator(MiVeCCConfig(rows=rows, cols=cols, density_vplh=a.density), a.batch,
                        seed=0)
        step = sim.step
        what = f"Simulator.step scheme E, B={a.batch}"
    for _ in range(a.warmup):
        step()
    prof = cProfile.Profile(time.process_time) if a.timer == "cpu" else cProfile.Profile()
    prof.enable()
    for _ in range(a.steps):
        step()
    prof.disable()
    rows_out = split(pstats.Stats(prof), a.steps)
    top = rows_out[0][1] if rows_out else 1.0
    print(f"{what}, {rows}x{cols}, {a.density:g} veh/lane/h, {a.steps} profiled steps, "
          f"{a.timer} time")
    print(f"{'phase':<45} {'us/step':>9} {'share':>7}")
    for label, us in rows_out:
        print(f"{label:<45} {us:>9.0f} {us / top:>7.0%}")
    return 0


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
