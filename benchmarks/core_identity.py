"""Bit-identity of the simulator core across two checkouts (old code vs optimised code).

Runs the same configurations in two source trees (each in its own subprocess with that tree
first on ``PYTHONPATH``), hashes every state array of the simulator and of its current
virtual-lane view after every step, and reports the first step where the two differ.
Configurations: grids 1x1 and 3x3; schemes E, EE (random edge actions), EEC (random edge and
cloud actions) and signalized; densities 300 and 2100 veh/lane/h (plus 900 and 1500 on 3x3 E);
B = 1 and 16.

Usage (the reference tree is, e.g., ``git worktree add --detach /tmp/ref <commit>``)::

    python benchmarks/core_identity.py --reference /tmp/ref --candidate . --steps 1200
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from mivecc_env import cli_args

STATE = ("active", "lane", "s", "v", "a", "t_arrive", "t_enter", "vid", "next_vid", "exited",
         "collided", "collision_events", "sum_travel_velocity", "sum_travel_velocity_no_wait",
         "sum_trip_time", "sum_wait_time", "sum_speed_samples", "vehicle_steps")
VIEW = ("vehicle", "env", "lane", "s", "point_group", "point_pos", "point_vehicle", "point_own",
        "point_run_start", "point_run_end", "own_point", "front_point", "back_point", "d_front",
        "d_back", "leader", "follower")


def configs() -> list[dict[str, Any]]:
    """The configurations compared (grid, scheme/control, density, batch)."""
    out = []
    for rows in (1, 3):
        for mode in ("E", "EE", "EEC", "signalized"):
            densities = (300, 900, 1500, 2100) if (rows, mode) == (3, "E") else (300, 2100)
            for density in densities:
                for batch in (1, 16):
                    out.append({"rows": rows, "mode": mode, "density": density, "batch": batch})
    return out


def trace(spec: dict[str, Any], steps: int, seed: int) -> list[str]:
    """Per-step digests of the state and the view of one configuration (run in-process)."""
    import numpy as np

    from mivecc_env.config import MiVeCCConfig
    from mivecc_env.sim.core import Simulator

    mode = spec["mode"]
    kw: dict[str, Any] = {"control": "signalized"} if mode == "signalized" else {"scheme": mode}
    cfg = MiVeCCConfig(rows=spec["rows"], cols=spec["rows"], density_vplh=float(spec["density"]),
                       **kw)
    sim = Simulator(cfg, batch_size=spec["batch"], seed=seed)
    rng = np.random.default_rng(seed + 1)
    out = []
    for _ in range(steps):
        edge = cloud = None
        if mode in ("EE", "EEC"):
            shape = sim.active.shape
            edge = np.where(rng.random(shape) < 0.7, rng.uniform(-3, 3, shape), np.nan)
            if mode == "EEC":
                cloud = np.where(rng.random(shape) < 0.5, rng.uniform(-3, 3, shape), np.nan)
        sim.step(edge, cloud)
        h = hashlib.sha1()
        for name in STATE:
            h.update(np.ascontiguousarray(getattr(sim, name)).tobytes())
        for arr in (sim.arrivals.arrived, sim.arrivals.entered):
            h.update(np.ascontiguousarray(arr).tobytes())
        for name in VIEW:
            h.update(np.ascontiguousarray(getattr(sim.view, name)).tobytes())
        for name in ("sv", "ttc"):
            h.update(np.ascontiguousarray(getattr(sim.safety, name)).tobytes())
        out.append(h.hexdigest()[:16])
    return out


def run_tree(tree: Path, specs: list[dict[str, Any]], steps: int, seed: int) -> list[list[str]]:
    """All traces computed by the code of ``tree`` (a subprocess with it on PYTHONPATH)."""
    extra = os.environ.get("PYTHONPATH", "")
    env = dict(os.environ, PYTHONPATH=str(tree.resolve()) + (os.pathsep + extra if extra else ""))
    here = str(Path(__file__).resolve().parent)
    code = (f"import json, sys; sys.path.insert(0, {here!r}); import core_identity as m; "
            "a = json.load(sys.stdin); "
            "print(json.dumps([m.trace(s, a['steps'], a['seed']) for s in a['specs']]))")
    res = subprocess.run([sys.executable, "-c", code], input=json.dumps(
        {"specs": specs, "steps": steps, "seed": seed}), capture_output=True, text=True,
        env=env, check=True)
    return json.loads(res.stdout)


def main(argv: list[str] | None = None) -> int:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--reference", type=Path, required=True, help="old source tree")
    p.add_argument("--candidate", type=Path, default=Path("."), help="new source tree")
    p.add_argument("--steps", type=cli_args.count(1), default=1200)
    p.add_argument("--seed", type=cli_args.seed, default=3)
    a = p.parse_args(argv)
    specs = configs()
    ref = run_tree(a.reference, specs, a.steps, a.seed)
    new = run_tree(a.candidate, specs, a.steps, a.seed)
    bad = 0
    for spec, x, y in zip(specs, ref, new, strict=True):
        first = next((i for i, (u, w) in enumerate(zip(x, y, strict=True)) if u != w), None)
        verdict = "identical" if first is None else f"DIFFERS from step {first + 1}"
        bad += first is not None
        print(f"{spec['rows']}x{spec['rows']} {spec['mode']:>10} {spec['density']:>5} "
              f"B={spec['batch']:<3} {a.steps} steps: {verdict}")
    print(f"{len(specs) - bad}/{len(specs)} configurations bit-identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
