"""Does the safety shield keep every vehicle apart whatever the coordinators command?

Runs MiVeCC-EEC on one batch of environments (every density x seed) with coordinator actions
no policy would choose, with and without ``safety_shield``, for each model:

* ``random``: every vehicle gets an edge and a cloud action drawn uniformly from [-3, 3] m/s^2
  on every step (a generator owned by this script, seeded by ``--action-seed``);
* ``plus3``: +3 m/s^2 from edge and cloud for every vehicle on every step (the most aggressive
  constant; the EE+3 / EEC+3 ceilings command only the picked vehicles);
* ``raw``: ``random``, with the edge action executed unmodified (no rule, no fusion) on every
  other step, as the released trainer explores (``raw_edge``).

Actions go to every vehicle (every slot), not only to the edges' and the cloud's picks, so the
rules are overridden far more often than by any policy. Prints, per model, actions and shield:
the vehicle-steps simulated, the strict collision events (two vehicles closer than
``vehicle_length_m``), the smallest centre distance and the released-style velocity.

Usage (3x3, both models, 7 densities x 3 seeds x 3000 steps; about 1.5 min here):
    python benchmarks/shield_stress.py
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import numpy as np
from paper_table import DENSITIES
from tqdm import tqdm

from mivecc_env import cli_args
from mivecc_env.config import MiVeCCConfig
from mivecc_env.metrics import batch_summary
from mivecc_env.sim.core import Simulator

ACTIONS = ("random", "plus3", "raw")


def stress_run(
    model: str, shield: bool, actions: str, rows: int, cols: int, densities: Sequence[float],
    seeds: Sequence[int], steps: int, action_seed: int,
) -> dict[str, float]:
    """One batch (densities x seeds) of ``steps`` steps; totals over the batch."""
    pairs = [(float(d), int(s)) for d in densities for s in seeds]
    config = MiVeCCConfig(rows=rows, cols=cols, scheme="EEC", model=model, safety_shield=shield,
                          max_steps=steps)
    sim = Simulator(config, batch_size=len(pairs), seed=[s for _, s in pairs],
                    densities=[d for d, _ in pairs])
    rng = np.random.default_rng(action_seed)
    a_max = config.a_max_mps2
    label = f"{model} {actions} shield={'on' if shield else 'off'}"
    raw = None
    for t in tqdm(range(steps), desc=label, unit="step", file=sys.stderr, mininterval=1.0):
        shape = sim.active.shape  # grows with the network: size the actions every step
        if actions == "plus3":
            edge = cloud = np.full(shape, a_max)
        else:
            edge, cloud = rng.uniform(-a_max, a_max, shape), rng.uniform(-a_max, a_max, shape)
        if actions == "raw":
            raw = np.full(sim.batch_size, t % 2 == 0)
        sim.step(edge_accel=edge, cloud_accel=cloud, raw_edge=raw)
    summary = batch_summary(sim)
    return {
        "vehicle_steps": float(sim.vehicle_steps.sum()),
        "collisions": float(sim.collision_events.sum()),
        "min_distance_m": float(summary["min_distance_m"].min()),
        "released_velocity_mps": float(np.mean(summary["released_velocity_mps"])),
    }


def table(rows: list[tuple[str, str, bool, dict[str, float]]]) -> str:
    lines = [
        "| model | actions | shield | vehicle-steps | strict collision events | "
        "min distance [m] | released-style v [m/s] |",
        "|---|---|---|---|---|---|---|",
    ]
    for model, actions, shield, r in rows:
        lines.append(
            f"| {model} | {actions} | {'on' if shield else 'off'} | {r['vehicle_steps']:.3g} | "
            f"{r['collisions']:.0f} | {r['min_distance_m']:.3f} | "
            f"{r['released_velocity_mps']:.3f} |")
    lines.append("\nTotals over every density x seed of the batch; min distance: the smallest "
                 "centre distance of any two vehicles (collided pairs included).")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> list[tuple[str, str, bool, dict[str, float]]]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=cli_args.grid, default=(3, 3))
    parser.add_argument("--densities", type=cli_args.density, nargs="+", default=list(DENSITIES))
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=cli_args.count(1), default=3000)
    parser.add_argument("--models", nargs="+", choices=("paper", "released"),
                        default=["paper", "released"])
    parser.add_argument("--actions", nargs="+", choices=ACTIONS, default=list(ACTIONS))
    parser.add_argument("--action-seed", type=cli_args.seed, default=0)
    args = parser.parse_args(argv)
    for option in ("seeds", "densities", "models", "actions"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))
    rows, cols = args.grid
    result = [
        (model, actions, shield,
         stress_run(model, shield, actions, rows, cols, args.densities, args.seeds, args.steps,
                    args.action_seed))
        for model in args.models for actions in args.actions for shield in (False, True)
    ]
    print(table(result))
    return result


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
