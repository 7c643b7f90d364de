"""Trace the strict collision events of one ParallelEnv episode of a MiVeCC scheme.

For every step with a collision event, prints the environment step, the intersection of each
collided vehicle (``Simulator.last_events.collided_area``) and, for the vehicles that vanished
without reaching their lane's end, their lane, position ``s`` [m], speed [m/s] and applied
acceleration (``a`` of the table) [m/s^2] over the ``--history`` steps before the event (from
``Simulator.vehicle_table``), and each such vehicle's distance past its lane's nearest
intersection centre when it made the colliding move (``past centre``: negative before it; the
released model's virtual lanes drop a vehicle more than ``section_control_end_m`` = 5 m past
it). Scheme ``E`` runs the rules alone; ``EE`` / ``EEC`` run the model's shipped policies (a
learned cloud at its checkpoint's ``cloud_period``), as ``mivecc evaluate`` does, or the
checkpoints given with ``--edge`` / ``--cloud``, on one torch thread like ``mivecc evaluate``
and ``paper_table.py`` (``--threads``), so its events are the table's. ``--set KEY=VALUE``
changes config fields as ``paper_table.py --set`` does.

Examples (E: the events of ``docs/results/released_study.md``, "Traced collisions"; EEC: the
shipped released pair's one event on the paper table's seeds, ``docs/training.md``):
    python benchmarks/trace_collisions.py --density 1500 --seed 1 --model released
    python benchmarks/trace_collisions.py --scheme EEC --density 2100 --seed 1 --model released
"""

from __future__ import annotations

import sys
from collections import deque
from typing import Any

import numpy as np
from paper_table import config_overrides

from mivecc_agents.cli import DEFAULT_EVAL_THREADS, set_inference_threads
from mivecc_agents.evaluation import evaluate_scheme
from mivecc_agents.policies import pretrained_policies
from mivecc_env import cli_args
from mivecc_env.config import from_overrides


class CollisionTracer:
    """A ``step_hook`` for :func:`evaluate_scheme` that records every strict collision event."""

    def __init__(self, history: int) -> None:
        self.tables: deque[dict[str, np.ndarray]] = deque(maxlen=history + 1)
        self.events = 0
        self.records: list[dict[str, Any]] = []

    def __call__(self, env: Any, t: int) -> None:
        sim = env.sim
        events = int(sim.collision_events[0])
        if t > 0 and events != self.events:
            self._report(sim, t - 1)
        self.events = events
        self.tables.append(sim.vehicle_table(0))

    def _report(self, sim: Any, step: int) -> None:
        before = self.tables[-1]
        idx = np.flatnonzero(~np.isin(before["vid"], sim.vehicle_table(0)["vid"]))
        # A vehicle whose next move cannot reach its lane's end was removed by the collision.
        lanes = before["lane"][idx]
        hit = before["s"][idx] + before["v"][idx] * sim.config.dt_s * 1.5 \
            < sim.network.lane_length[lanes]
        vids = before["vid"][idx][hit].tolist()
        areas = sim.last_events.collided_area.tolist()
        past = past_centre_m(sim.network.lane_centres_s, before["lane"][idx][hit],
                             before["s"][idx][hit])
        print(f"== step {step} (t = {(step + 1) * sim.config.dt_s:.1f} s): vehicles {vids}, "
              f"intersections {areas}, past centre [m] "
              f"{[round(float(x), 2) for x in past]}")
        first = step - len(self.tables) + 1
        for k, table in enumerate(self.tables):
            cells = []
            for vid in vids:
                i = np.flatnonzero(table["vid"] == vid)
                cells.append("--" if i.size == 0 else
                             f"v{vid} lane {table['lane'][i[0]]} s={table['s'][i[0]]:7.2f} "
                             f"v={table['v'][i[0]]:5.2f} a={table['a'][i[0]]:5.2f}")
            print(f"  step {first + k:5d}  " + "  |  ".join(cells))
        self.records.append({"step": step, "vehicles": vids, "areas": areas,
                             "past_centre_m": past.tolist()})


def past_centre_m(lane_centres_s: np.ndarray, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Signed distance [m] of each position ``s`` on ``lane`` past the lane's nearest
    intersection centre (negative before it); ``lane_centres_s`` is the network's
    (n_lanes, n) table, padded with non-finite values."""
    centres = lane_centres_s[lane]
    offset = np.where(np.isfinite(centres), s[:, None] - centres, np.inf)
    return offset[np.arange(len(s)), np.argmin(np.abs(offset), axis=1)]


#: Config fields this script's own options set (not accepted by --set).
OWN_FIELDS = {"rows": "--rows", "cols": "--cols", "density_vplh": "--density",
              "scheme": "--scheme", "max_steps": "--steps", "model": "--model"}


def main(argv: list[str] | None = None) -> list[dict]:
    """Run one episode and return one record per step with a collision event."""
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=cli_args.count(1), default=3)
    p.add_argument("--cols", type=cli_args.count(1), default=3)
    p.add_argument("--density", type=cli_args.density, default=2100.0, help="veh/lane/h")
    p.add_argument("--seed", type=cli_args.seed, default=0)
    p.add_argument("--steps", type=cli_args.count(1), default=3000)
    p.add_argument("--model", default="released", choices=["paper", "released"])
    p.add_argument("--scheme", default="E", choices=["E", "EE", "EEC"],
                   help="EE / EEC act with the model's shipped policies")
    p.add_argument("--history", type=cli_args.count(0), default=30,
                   help="steps printed before an event")
    p.add_argument("--edge", default=None, help="edge checkpoint (default: the shipped one)")
    p.add_argument("--cloud", default=None, help="cloud checkpoint (default: the shipped one)")
    p.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", default=[],
                   help="other config fields, e.g. cloud_graphs=per_lane (as paper_table.py)")
    p.add_argument("--threads", type=cli_args.count(1), default=DEFAULT_EVAL_THREADS,
                   help="torch threads of the policies (default %(default)s, as `mivecc "
                        "evaluate` and paper_table.py: another count rounds the networks "
                        "differently, and the episode drifts from the table's)")
    args = p.parse_args(argv)
    if args.scheme == "E" and (args.edge or args.cloud):
        p.error("--edge / --cloud: only with --scheme EE or EEC (E runs the rules alone)")
    overrides = config_overrides(args.set_items, args.model, OWN_FIELDS)
    if args.scheme != "E":
        set_inference_threads(args.threads)

    shield = from_overrides(model=args.model, **overrides).safety_shield
    policies = (pretrained_policies(args.model, edge=args.edge, cloud=args.cloud,
                                    safety_shield=shield)
                if args.scheme != "E" else {})
    tracer = CollisionTracer(args.history)
    result = evaluate_scheme(args.scheme, args.rows, args.cols, args.density, args.steps,
                             args.seed, policies=policies, progress=False, model=args.model,
                             step_hook=tracer, **overrides)
    print(f"collision events: {int(result['collisions'])}")
    return tracer.records


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
