"""Does the edge's training reward rank edge behaviours like the metric does?

Runs MiVeCC-EE with constant edges (the same action in every decision column; by default
0, +1, +2 and +3 m/s^2) and with a learned edge (a checkpoint, or the model's shipped one),
all (density, seed) pairs of a variant as one batch. Prints, per variant, the mean stage-I
reward per node and step (the edge reward the trainer optimises, after ``--skip`` fill-up
steps), the released-style velocity, this project's average travel velocity and the strict
collision events.

The edge reward is the env's, so its fields must be the training run's: ``--set`` them as
the run did (the released preset's are ``reward_sv_weight=1 edge_reward_scope=decisions
collision_penalty=0``, and a run's ``--set`` comes on top). If the reward ranks the constant
+3 edge above the learned one, as the velocity does, a learned edge below the +3 ceiling
falls short for lack of learning, not because of its reward.

Usage (about 30 s on 1x1 on an idle 2-core machine):
    python benchmarks/edge_reward_check.py --model released --rows 1 --cols 1 \
        --set reward_sv_weight=0 edge_reward_scope=decisions collision_penalty=0 \
        safety_shield=true --out benchmarks/results
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from paper_table import config_overrides

from mivecc_agents.evaluation import evaluate_batch
from mivecc_agents.policies import Policy, constant_policy, load_policy, pretrained_path
from mivecc_env import cli_args
from mivecc_env.config import from_overrides

CONSTANTS_MPS2 = (0.0, 1.0, 2.0, 3.0)

#: Config fields this script's own options set (not accepted by --set).
OWN_FIELDS = {"rows": "--rows", "cols": "--cols", "density_vplh": "--densities",
              "max_steps": "--steps", "model": "--model"}


def run_variant(
    model: str, rows: int, cols: int, densities: Sequence[float], seeds: Sequence[int],
    steps: int, skip: int, edge: Policy, overrides: dict[str, Any],
) -> dict[str, Any]:
    """One batch of every (density, seed) pair of MiVeCC-EE with the given edge policy."""
    sums = {"edge_reward": 0.0, "t": 0}

    def record(_before: Any, _edge: Any, _cloud: Any, after: Any) -> None:
        if sums["t"] >= skip:
            sums["edge_reward"] += float(after.edge_reward.mean())
        sums["t"] += 1

    results = evaluate_batch("EE", rows, cols, densities, steps, seeds, policies={"edge": edge},
                             progress=False, warn=False, on_step=record, model=model,
                             stack_policies=True,  # as when its documented outputs were made
                             **overrides)
    return {
        "edge_reward": sums["edge_reward"] / max(steps - skip, 1),
        "released_velocity_mps": float(np.mean([r["released_velocity_mps"] for r in results])),
        "avg_travel_velocity_mps": float(np.mean([r["avg_travel_velocity_mps"]
                                                  for r in results])),
        "collisions": int(sum(r["collisions"] for r in results)),
    }


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("paper", "released"), default="released")
    parser.add_argument("--rows", type=cli_args.count(1), default=1)
    parser.add_argument("--cols", type=cli_args.count(1), default=1)
    parser.add_argument("--densities", type=cli_args.density, nargs="+",
                        default=[900.0, 1500.0, 2100.0])
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1])
    parser.add_argument("--steps", type=cli_args.count(1), default=2000)
    parser.add_argument("--skip", type=cli_args.count(0), default=500,
                        help="fill-up steps left out of the mean reward")
    parser.add_argument("--constants", type=cli_args.number(-3.0, 3.0), nargs="*",
                        default=list(CONSTANTS_MPS2), help="constant edge actions [m/s^2]")
    parser.add_argument("--edge", type=Path, default=None,
                        help="an edge checkpoint to check instead of the model's shipped one")
    parser.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", default=[],
                        help="config fields, the training run's reward fields among them")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    if not 0 <= args.skip < args.steps:
        parser.error(f"--skip: must be in [0, --steps - 1] = [0, {args.steps - 1}], "
                     f"got {args.skip}")
    overrides = config_overrides(args.set_items, args.model, OWN_FIELDS)
    if "scheme" in overrides:
        parser.error("--set scheme: this check always runs MiVeCC-EE")
    shield = from_overrides(model=args.model, **overrides).safety_shield
    path = args.edge if args.edge is not None else pretrained_path("edge", args.model, shield)
    if path is None:
        parser.error(f"--edge: no shipped edge for model {args.model!r}; name a checkpoint")
    torch.set_num_threads(1)
    learned = load_policy(path, expected_kind="edge")
    variants: list[tuple[str, Policy]] = [
        (f"constant {c:+g} m/s^2", constant_policy("edge", c, learned.grid_size))
        for c in args.constants
    ]
    variants.append((f"learned ({path})", learned))
    rows = []
    for name, policy in variants:
        t0 = time.perf_counter()
        row = {"edge": name, **run_variant(args.model, args.rows, args.cols, args.densities,
                                          args.seeds, args.steps, args.skip, policy,
                                          overrides)}
        rows.append(row)
        print(f"{name:44s} reward {row['edge_reward']:+.4f}  released-style v "
              f"{row['released_velocity_mps']:.4f}  average travel v "
              f"{row['avg_travel_velocity_mps']:.4f}  events {row['collisions']}  "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    command = " ".join(["python benchmarks/edge_reward_check.py", *(argv or sys.argv[1:])])
    lines = [
        f"Command: `{command}`",
        "",
        f"MiVeCC-EE, {args.rows}x{args.cols}, {' / '.join(f'{d:g}' for d in args.densities)} "
        f"veh/lane/h, seeds {' '.join(map(str, args.seeds))}, {args.steps} steps; the reward is "
        f"the mean edge reward per node and step after {args.skip} fill-up steps.",
        "",
        "| edge | mean edge reward | released-style v [m/s] | average travel v [m/s] | "
        "strict events |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {r['edge']} | {r['edge_reward']:+.4f} | {r['released_velocity_mps']:.4f} | "
              f"{r['avg_travel_velocity_mps']:.4f} | {r['collisions']} |" for r in rows]
    out = args.out / f"edge_reward_check_{args.model}.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")
    return rows


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
