"""Trace the strict collision events of one ParallelEnv episode (MiVeCC-E, zero actions).

For every step with a collision event, prints the environment step, the intersection of each
collided vehicle (``Simulator.last_events.collided_area``) and, for the vehicles that vanished
without reaching their lane's end, their lane, position ``s`` [m], speed [m/s] and applied
acceleration (``a`` of the table) [m/s^2] over the ``--history`` steps before the event (from
``Simulator.vehicle_table``, read before each step).

Example (the two events of ``docs/results/released_study.md``, "Traced collisions"):
    python benchmarks/trace_collisions.py --density 1500 --seed 1 --model released
"""

from __future__ import annotations

import argparse
from collections import deque

import numpy as np

from mivecc_env import mivecc_v0


def main(argv: list[str] | None = None) -> list[dict]:
    """Run one episode and return one record per step with a collision event."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, default=3)
    p.add_argument("--cols", type=int, default=3)
    p.add_argument("--density", type=float, default=2100.0, help="veh/lane/h")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--model", default="released", choices=["paper", "released"])
    p.add_argument("--history", type=int, default=30, help="steps printed before an event")
    args = p.parse_args(argv)

    env = mivecc_v0.parallel_env(rows=args.rows, cols=args.cols, density=args.density,
                                 scheme="E", model=args.model, max_steps=args.steps)
    env.reset(seed=args.seed)
    sim = env.sim
    actions = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents}
    history: deque[dict[str, np.ndarray]] = deque(maxlen=args.history + 1)
    records = []
    for step in range(args.steps):
        before = sim.vehicle_table(0)
        history.append(before)
        events_before = int(sim.collision_events[0])
        env.step(actions)
        if int(sim.collision_events[0]) == events_before:
            continue
        idx = np.flatnonzero(~np.isin(before["vid"], sim.vehicle_table(0)["vid"]))
        # A vehicle whose next move cannot reach its lane's end was removed by the collision.
        lanes = before["lane"][idx]
        hit = before["s"][idx] + before["v"][idx] * sim.config.dt_s * 1.5 \
            < sim.network.lane_length[lanes]
        vids = before["vid"][idx][hit].tolist()
        areas = sim.last_events.collided_area.tolist()
        print(f"== step {step} (t = {(step + 1) * sim.config.dt_s:.1f} s): vehicles {vids}, "
              f"intersections {areas}")
        for k, table in enumerate(history):
            cells = []
            for vid in vids:
                i = np.flatnonzero(table["vid"] == vid)
                cells.append("--" if i.size == 0 else
                             f"v{vid} lane {table['lane'][i[0]]} s={table['s'][i[0]]:7.2f} "
                             f"v={table['v'][i[0]]:5.2f} a={table['a'][i[0]]:5.2f}")
            print(f"  step {step - len(history) + 1 + k:5d}  " + "  |  ".join(cells))
        records.append({"step": step, "vehicles": vids, "areas": areas})
    print(f"collision events: {int(sim.collision_events[0])}")
    return records


if __name__ == "__main__":
    main()
