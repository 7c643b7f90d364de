"""Does the cloud's training reward rank cloud behaviours like the metric does?

Runs MiVeCC-EEC with the model's shipped edge policy and, as the cloud, constant actions
(-3, 0, +1, +3 m/s^2 in every decision column) and the model's shipped cloud policy, all
(density, seed) pairs of a variant as one batch. Prints, per variant, the mean stage-II
reward per step (the cloud reward the trainer optimises, after ``--skip`` fill-up steps),
the mean edge reward, the released-style velocity and this project's average travel
velocity, strict collision events, and the shipped cloud's mean action over the real
columns of its decisions. If the reward orders the constant actions as the velocity does, a
cloud that fails to reach the +3 ceiling fails for lack of learning, not because of its
reward.

Usage (about 1 min on an idle 2-core machine):
    python benchmarks/cloud_reward_check.py --model released --out benchmarks/results
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mivecc_agents.evaluation import evaluate_batch
from mivecc_agents.policies import Policy, constant_policy, load_policy, pretrained_policies
from mivecc_env import cli_args

CONSTANTS_MPS2 = (-3.0, 0.0, 1.0, 3.0)


def run_variant(
    model: str, rows: int, cols: int, densities: Sequence[float], seeds: Sequence[int],
    steps: int, skip: int, edge: Policy, cloud: Policy, cloud_period: int | None = None,
) -> dict[str, Any]:
    """One batch of every (density, seed) pair with the given edge and cloud policies, the
    cloud deciding every ``cloud_period`` steps (default: a learned cloud's training period,
    a constant cloud every step)."""
    sums = {"cloud_reward": 0.0, "edge_reward": 0.0, "action": 0.0, "columns": 0, "t": 0}

    def record(before: Any, _edge: Any, cloud_action: np.ndarray, after: Any) -> None:
        real = (before.cloud_mask > 0) & ~np.isnan(cloud_action)  # NaN: no decision
        sums["action"] += float(cloud_action[real].sum())
        sums["columns"] += int(real.sum())
        if sums["t"] >= skip:
            sums["cloud_reward"] += float(after.cloud_reward.mean())
            sums["edge_reward"] += float(after.edge_reward.mean())
        sums["t"] += 1

    results = evaluate_batch("EEC", rows, cols, densities, steps, seeds,
                             policies={"edge": edge, "cloud": cloud}, progress=False,
                             warn=False, on_step=record, model=model,
                             stack_policies=True,  # as when its documented outputs were made
                             **({} if cloud_period is None else {"cloud_period": cloud_period}))
    n = max(steps - skip, 1)
    return {
        "cloud_period": int(results[0]["cloud_period"]),
        "cloud_reward": sums["cloud_reward"] / n,
        "edge_reward": sums["edge_reward"] / n,
        "released_velocity_mps": float(np.mean([r["released_velocity_mps"] for r in results])),
        "avg_travel_velocity_mps": float(np.mean([r["avg_travel_velocity_mps"]
                                                  for r in results])),
        "collisions": int(sum(r["collisions"] for r in results)),
        "mean_cloud_action_mps2": sums["action"] / max(sums["columns"], 1),
    }


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("paper", "released"), default="released")
    parser.add_argument("--rows", type=cli_args.count(1), default=3)
    parser.add_argument("--cols", type=cli_args.count(1), default=3)
    parser.add_argument("--densities", type=cli_args.density, nargs="+", default=[1500.0, 2100.0])
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1])
    parser.add_argument("--steps", type=cli_args.count(1), default=2000)
    parser.add_argument("--constants", type=cli_args.number(-3.0, 3.0), nargs="*",
                        default=list(CONSTANTS_MPS2),
                        help="constant cloud actions to run [m/s^2]")
    parser.add_argument("--skip", type=cli_args.count(0), default=500,
                        help="fill-up steps left out of the mean rewards")
    parser.add_argument("--cloud", type=Path, default=None,
                        help="a cloud checkpoint to check instead of the model's shipped one")
    parser.add_argument("--cloud-period", type=cli_args.count(1), default=None,
                        help="steps between cloud decisions of every variant (default: a "
                        "learned cloud's training period, the constant clouds every step)")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    if args.cloud_period is not None and not 1 <= args.cloud_period <= 1000:
        parser.error(f"--cloud-period: must be in [1, 1000] steps, got {args.cloud_period}")
    if not 0 <= args.skip < args.steps:
        parser.error(f"--skip: must be in [0, --steps - 1] = [0, {args.steps - 1}], "
                     f"got {args.skip}")
    bad = [a for a in args.constants if not -3.0 <= a <= 3.0]
    if bad:
        parser.error(f"--constants: each must be in [-3, 3] m/s^2, got {bad}")
    shipped = pretrained_policies(args.model)
    grid = max(args.rows, args.cols)
    variants: list[tuple[str, Policy]] = [
        (f"constant {a:+g}", constant_policy("cloud", a, grid)) for a in args.constants
    ]
    if args.cloud is None:
        variants.append(("shipped cloud", shipped["cloud"]))
    else:
        variants.append((f"cloud {args.cloud}", load_policy(args.cloud, expected_kind="cloud")))
    rows = []
    for name, cloud in variants:
        t0 = time.perf_counter()
        r = run_variant(args.model, args.rows, args.cols, args.densities, args.seeds,
                        args.steps, args.skip, shipped["edge"], cloud, args.cloud_period)
        rows.append({"cloud": name, **r})
        print(f"{name:14s} cloud reward {r['cloud_reward']:+.4f}/step  "
              f"v455 {r['released_velocity_mps']:.3f}  v {r['avg_travel_velocity_mps']:.3f} "
              f"m/s  collisions {r['collisions']}  period {r['cloud_period']}  mean action "
              f"{r['mean_cloud_action_mps2']:+.3f} m/s^2  ({time.perf_counter() - t0:.0f} s)",
              flush=True)
    path = args.out / f"cloud_reward_check_{args.model}.md"
    lines = [
        f"Command: `python benchmarks/cloud_reward_check.py --model {args.model} --rows "
        f"{args.rows} --cols {args.cols} --densities {' '.join(f'{d:g}' for d in args.densities)}"
        f" --seeds {' '.join(map(str, args.seeds))} --steps {args.steps} --skip {args.skip}"
        f" --constants {' '.join(f'{a:g}' for a in args.constants)}"
        + (f" --cloud {args.cloud}" if args.cloud else "")
        + (f" --cloud-period {args.cloud_period}" if args.cloud_period else "") + "`",
        "",
        "| cloud | decides every [steps] | cloud reward per step | edge reward per step | "
        "released-style v [m/s] | avg travel v [m/s] | collisions | mean cloud action [m/s^2] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['cloud']} | {r['cloud_period']} | {r['cloud_reward']:+.4f} | "
        f"{r['edge_reward']:+.4f} | "
        f"{r['released_velocity_mps']:.3f} | {r['avg_travel_velocity_mps']:.3f} | "
        f"{r['collisions']} | {r['mean_cloud_action_mps2']:+.3f} |" for r in rows
    ]
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")
    return rows


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
