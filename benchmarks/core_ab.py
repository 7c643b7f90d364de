"""Bare-core speed of two source trees, interleaved (A, B, A, B, ...) in one run.

Each round runs ``Simulator.step`` of each tree in its own subprocess (that tree first on
``PYTHONPATH``): ``--warmup`` untimed steps, then ``--steps`` timed steps, 3x3 grid, scheme E,
no actions. Prints microseconds per step of every round and the ratio of the medians, so that
load from other processes hits both trees alike.

Usage::

    git worktree add --detach /tmp/ref <old commit>
    python benchmarks/core_ab.py --trees /tmp/ref . --batch 64 --steps 200 --rounds 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys

CODE = r"""
import sys, time
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator
batch, steps, warmup = (int(x) for x in sys.argv[1:4])
cfg = MiVeCCConfig(rows=3, cols=3, density_vplh=float(sys.argv[4]), scheme="E")
sim = Simulator(cfg, batch_size=batch, seed=0)
for _ in range(warmup):
    sim.step()
t0 = time.perf_counter()
for _ in range(steps):
    sim.step()
print((time.perf_counter() - t0) / steps * 1e6)
"""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trees", nargs=2, required=True, help="old and new source trees")
    p.add_argument("--batch", type=int, default=1)
    p.add_argument("--density", type=float, default=2100.0)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--warmup", type=int, default=600)
    p.add_argument("--rounds", type=int, default=3)
    a = p.parse_args(argv)
    times: dict[str, list[float]] = {t: [] for t in a.trees}
    for _ in range(a.rounds):
        for tree in a.trees:
            env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
            out = subprocess.run(
                [sys.executable, "-c", CODE, str(a.batch), str(a.steps), str(a.warmup),
                 str(a.density)], env=env, capture_output=True, text=True, check=True,
                cwd=os.path.abspath(tree))
            times[tree].append(float(out.stdout.strip()))
    old, new = (statistics.median(times[t]) for t in a.trees)
    for tree in a.trees:
        print(f"{tree}: " + ", ".join(f"{x:.0f}" for x in times[tree]) + " us/step")
    print(f"3x3, {a.density:g} veh/lane/h, B={a.batch}: median {old:.0f} -> {new:.0f} us/step, "
          f"speed-up {old / new:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
