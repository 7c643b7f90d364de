"""How many vehicles the cloud commands: one network graph against the paper's per-lane graphs.

Runs MiVeCC-E traffic (the on-board rules alone; the cloud observes but does not act) on one
batch of environments, every density x seed, and samples every ``--every`` steps after
``--warmup`` steps:

* the cloud's pick population (``cloud_pick_population`` of the model),
* the most eligible vehicles on one through lane (per-lane graphs pick them all while it is at
  most ``k_cloud``),
* the picks of one network graph (``cloud_graphs="network"``, at most ``k_cloud``) and of the
  per-lane graphs (``"per_lane"``), and the share of the population each commands.

Usage (3x3, both models, about 1 min each here):
    python benchmarks/cloud_pick_counts.py --model released
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import numpy as np
from paper_table import DENSITIES
from tqdm import tqdm

from mivecc_env import cli_args
from mivecc_env.batched import BatchedMiVeCCEnv


def sample_picks(
    rows: int, cols: int, densities: Sequence[float], seeds: Sequence[int], steps: int,
    warmup: int, every: int, model: str,
) -> dict[float, dict[str, float]]:
    """Per density: mean population, mean and max eligible vehicles per lane, mean picks of
    the network graph and of the per-lane graphs (over the samples and seeds)."""
    pairs = [(float(d), int(s)) for d in densities for s in seeds]
    envs = {
        graphs: BatchedMiVeCCEnv(
            batch_size=len(pairs), densities=[d for d, _ in pairs], rows=rows, cols=cols,
            scheme="EEC", model=model, cloud_graphs=graphs, observe={"cloud"},
            max_steps=steps)
        for graphs in ("network", "per_lane")
    }
    samples: dict[str, list[np.ndarray]] = {"population": [], "lane_max": [], "network": [],
                                            "per_lane": []}
    for env in envs.values():
        env.reset(seed=[s for _, s in pairs])
    for t in tqdm(range(1, steps + 1), desc=f"{model} {rows}x{cols}", unit="step",
                  file=sys.stderr, mininterval=0.5):
        outs = {g: env.step(None, None) for g, env in envs.items()}  # E: the rules alone
        if t <= warmup or t % every:
            continue
        lane_picks = outs["per_lane"].cloud_mask.sum(axis=2)  # (B, n_lanes)
        samples["population"].append(lane_picks.sum(axis=1))
        samples["lane_max"].append(lane_picks.max(axis=1))
        samples["network"].append(outs["network"].cloud_mask.sum(axis=1))
        samples["per_lane"].append(lane_picks.sum(axis=1))
    arr = {k: np.stack(v) for k, v in samples.items()}  # (samples, B)
    n_lanes = envs["per_lane"].config.n_cloud_graphs
    out: dict[float, dict[str, float]] = {}
    for d in dict.fromkeys(d for d, _ in pairs):
        cols_d = [j for j, (dd, _) in enumerate(pairs) if dd == d]
        pick = {k: v[:, cols_d] for k, v in arr.items()}
        out[d] = {
            "population": float(pick["population"].mean()),
            "lane_mean": float(pick["population"].mean() / n_lanes),
            "lane_max": float(pick["lane_max"].max()),
            "network": float(pick["network"].mean()),
            "per_lane": float(pick["per_lane"].mean()),
        }
    return out


def table(result: dict[float, dict[str, float]], k: int) -> str:
    lines = [
        "| veh/lane/h | pick population | eligible per lane (mean / max) | network graph picks "
        "(share) | per-lane graphs picks (share) |",
        "|---|---|---|---|---|",
    ]
    for d, r in result.items():
        pop = max(r["population"], 1e-9)
        lines.append(
            f"| {d:g} | {r['population']:.1f} | {r['lane_mean']:.1f} / {r['lane_max']:.0f} | "
            f"{r['network']:.1f} ({100 * r['network'] / pop:.0f} %) | "
            f"{r['per_lane']:.1f} ({100 * r['per_lane'] / pop:.0f} %) |")
    lines.append(f"\nK = {k} per graph; means over the samples and seeds, max over both.")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> dict[float, dict[str, float]]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=cli_args.grid, default=(3, 3))
    parser.add_argument("--densities", type=cli_args.density, nargs="+", default=list(DENSITIES))
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=cli_args.count(1), default=3000)
    parser.add_argument("--warmup", type=cli_args.count(0), default=1000,
                        help="steps before the first sample (the network filling up)")
    parser.add_argument("--every", type=cli_args.count(1), default=10)
    parser.add_argument("--model", choices=("paper", "released"), default="released")
    args = parser.parse_args(argv)
    for option in ("seeds", "densities"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))
    if args.warmup >= args.steps:
        parser.error(f"--warmup: must be below --steps ({args.steps}), got {args.warmup}")
    rows, cols = args.grid
    result = sample_picks(rows, cols, args.densities, args.seeds, args.steps, args.warmup,
                          args.every, args.model)
    k = BatchedMiVeCCEnv(batch_size=1, rows=rows, cols=cols, model=args.model).k_cloud
    print(table(result, k))
    return result


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
