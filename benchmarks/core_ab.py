"""Speed of two source trees, interleaved (A, B, A, B, ...) in one run.

Each round runs the step of each tree in its own subprocess (that tree first on
``PYTHONPATH``): ``--warmup`` untimed steps, then ``--steps`` timed steps, 3x3 grid. Prints
microseconds per step of every round and the ratio of the medians, so that load from other
processes hits both trees alike. ``--what`` picks the step: ``core`` (``Simulator.step``,
scheme E, no actions; the default), ``batched`` (``BatchedMiVeCCEnv.step``, scheme EEC with
EEC observations; warm-up with bare core steps, then 20 env steps) or ``E``/``EE``/``EEC``
(``MiVeCCParallelEnv.step`` of that scheme with zero actions). ``--clock cpu`` times the
process's CPU time instead of wall time (steadier on a shared machine).

Usage::

    git worktree add --detach /tmp/ref <old commit>
    python benchmarks/core_ab.py --trees /tmp/ref . --batch 64 --steps 200 --rounds 3
    python benchmarks/core_ab.py --trees /tmp/ref . --what batched --batch 64 --steps 60 \
        --clock cpu
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys

from mivecc_env import cli_args

CODE = r"""
import sys, time
import numpy as np
what, batch, steps, warmup = sys.argv[1], *(int(x) for x in sys.argv[2:5])
density, clock = float(sys.argv[5]), sys.argv[6]
if what == "core":
    from mivecc_env.config import MiVeCCConfig
    from mivecc_env.sim.core import Simulator
    cfg = MiVeCCConfig(rows=3, cols=3, density_vplh=density, scheme="E")
    sim = Simulator(cfg, batch_size=batch, seed=0)
    step = sim.step
    for _ in range(warmup):
        step()
elif what == "batched":
    from mivecc_env.batched import BatchedMiVeCCEnv
    env = BatchedMiVeCCEnv(batch_size=batch, rows=3, cols=3, density=density, scheme="EEC",
                           max_steps=warmup + steps + 100)
    env.reset(seed=0)
    for _ in range(warmup):
        env.sim.step()
    for _ in range(20):
        env.step()
    step = env.step
else:
    from mivecc_env import mivecc_v0
    env = mivecc_v0.parallel_env(rows=3, cols=3, density=density, scheme=what,
                                 max_steps=warmup + steps + 100)
    env.reset(seed=0)
    act = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents}
    step = lambda: env.step(act)
    for _ in range(warmup):
        step()
timer = time.process_time if clock == "cpu" else time.perf_counter
t0 = timer()
for _ in range(steps):
    step()
print((timer() - t0) / steps * 1e6)
"""


def main(argv: list[str] | None = None) -> int:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--trees", nargs=2, required=True, help="old and new source trees")
    p.add_argument("--batch", type=cli_args.count(1), default=1)
    p.add_argument("--density", type=cli_args.density, default=2100.0)
    p.add_argument("--steps", type=cli_args.count(1), default=1000)
    p.add_argument("--warmup", type=cli_args.count(0), default=600)
    p.add_argument("--rounds", type=cli_args.count(1), default=3)
    p.add_argument("--what", choices=("core", "batched", "E", "EE", "EEC"), default="core",
                   help="which step (see the module docstring)")
    p.add_argument("--clock", choices=("wall", "cpu"), default="wall")
    a = p.parse_args(argv)
    times: dict[str, list[float]] = {t: [] for t in a.trees}
    for _ in range(a.rounds):
        for tree in a.trees:
            env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
            out = subprocess.run(
                [sys.executable, "-c", CODE, a.what, str(a.batch), str(a.steps), str(a.warmup),
                 str(a.density), a.clock], env=env, capture_output=True, text=True, check=True,
                cwd=os.path.abspath(tree))
            times[tree].append(float(out.stdout.strip()))
    old, new = (statistics.median(times[t]) for t in a.trees)
    for tree in a.trees:
        print(f"{tree}: " + ", ".join(f"{x:.0f}" for x in times[tree]) + " us/step")
    print(f"{a.what}, 3x3, {a.density:g} veh/lane/h, B={a.batch}, {a.clock} time: "
          f"median {old:.0f} -> {new:.0f} us/step, speed-up {old / new:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
