"""In-step A/B of the near-miss hook and of ``collision_pairs``: this tree's against another's.

One simulator of this tree steps; at every step its near-miss hook feeds the same arguments to a
``NearMissStats`` of each tree (fresh, after the warm-up), in alternating order, and times each
call (CPU time of this process, so load from other processes counts less). The inputs are as
warm in the cache as in a real step. At the end the accumulators of both must be identical.
The compiled ``step_kernels.collision_pairs`` of both trees is timed the same way on the same
arguments (its results compared at every step).
The other tree's ``near_miss.py`` and ``near_miss_kernel.py`` are loaded from its files under
other module names (its ``near_miss.py`` with its kernel import pointed at its own kernel).

Usage::

    git worktree add --detach /tmp/ref <old commit>
    python benchmarks/near_miss_ab.py --ref /tmp/ref --batch 64 --steps 200
    python benchmarks/near_miss_ab.py --ref /tmp/ref --batch 1 --steps 3000
"""

from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path
from types import ModuleType

import numpy as np

from mivecc_env import cli_args
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import step_kernels
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.near_miss import NearMissStats

FIELDS = ("min_ttc_s", "ttc_hist", "min_pet_s", "pet_samples", "pet_under", "min_distance_m",
          "last_leave_s", "last_leave_side")


def load_reference(tree: Path) -> ModuleType:
    """The other tree's ``near_miss`` module (with its own kernel module)."""
    sim = tree / "mivecc_env" / "sim"
    spec = importlib.util.spec_from_file_location("_ref_near_miss_kernel",
                                                  sim / "near_miss_kernel.py")
    kernel = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = kernel
    spec.loader.exec_module(kernel)
    source = (sim / "near_miss.py").read_text()
    source = source.replace("from mivecc_env.sim import near_miss_kernel",
                            "import _ref_near_miss_kernel as near_miss_kernel")
    module = ModuleType("_ref_near_miss")
    module.__file__ = str(sim / "near_miss.py")
    sys.modules[module.__name__] = module
    exec(compile(source, module.__file__, "exec"), module.__dict__)
    return module


def load_reference_step_kernels(tree: Path) -> ModuleType:
    """The other tree's ``step_kernels`` module."""
    path = tree / "mivecc_env" / "sim" / "step_kernels.py"
    spec = importlib.util.spec_from_file_location("_ref_step_kernels", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--ref", type=Path, required=True, help="the other source tree")
    p.add_argument("--batch", type=cli_args.count(1), default=64)
    p.add_argument("--density", type=cli_args.density, default=2100.0)
    p.add_argument("--warmup", type=cli_args.count(0), default=400)
    p.add_argument("--steps", type=cli_args.count(1), default=200)
    a = p.parse_args()
    ref_module = load_reference(a.ref)
    kernels = {"ref": load_reference_step_kernels(a.ref), "this": step_kernels}
    cfg = MiVeCCConfig(density_vplh=a.density)
    sim = Simulator(cfg, batch_size=a.batch, seed=0)
    for _ in range(a.warmup):
        sim.step()
    stats = {"ref": ref_module.NearMissStats(sim.network, a.batch, cfg.vehicle_length_m),
             "this": NearMissStats(sim.network, a.batch, cfg.vehicle_length_m)}
    total: dict[str, float] = {}
    total_pairs: dict[str, float] = {}
    calls = [0]
    net = sim.network

    def both(view, v, s_new, gone, t0, dt) -> None:
        names = ["ref", "this"] if calls[0] % 2 == 0 else ["this", "ref"]
        calls[0] += 1
        pairs = {}
        for name in names:
            t = time.process_time()
            stats[name].record_step(view, v, s_new, gone, t0, dt)
            total[name] += time.process_time() - t
            t = time.process_time()
            pairs[name] = kernels[name].collision_pairs(
                view.leader, s_new, gone, view.lane, view.env, net.lane_cp, net.lane_cp_s,
                net.n_cp, net.segment_length_m, net.lane_offset_m, cfg.vehicle_length_m)
            total_pairs[name] += time.process_time() - t
        assert np.array_equal(pairs["ref"], pairs["this"])

    sim.near_miss.record_step = both
    for _ in range(5):  # compile both kernels; these steps are not timed
        sim.step()
    total = dict.fromkeys(stats, 0.0)
    total_pairs = dict.fromkeys(stats, 0.0)
    for _ in range(a.steps):
        sim.step()
    for name in FIELDS:
        assert np.array_equal(getattr(stats["ref"], name), getattr(stats["this"], name)), name
    head = f"3x3, {a.density:g} veh/lane/h, B={a.batch}, {a.steps} steps, cpu time"
    for what, tot in (("record_step", total), ("collision_pairs", total_pairs)):
        us = {k: v / a.steps * 1e6 for k, v in tot.items()}
        print(f"{what}, {head}: ref {us['ref']:.1f} us, this {us['this']:.1f} us, speed-up "
              f"{tot['ref'] / tot['this']:.2f}x (results identical)")


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
