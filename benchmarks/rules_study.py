"""Collision and efficiency study of the end-node rule readings (MiVeCC-E, rules only).

Runs the bare simulator (scheme E) on a grid for several densities, seeds and rule readings
(all densities and seeds of a reading as one batched simulator; each environment equals a
B = 1 run of its seed):

* ``sensible``: nearest ahead -> SV/eta, nearest behind -> |SV/eta|,
* ``literal``: Algorithm 3 as printed,
* ``+same_lane``: plus the released code's same-lane rule,
* ``acc=front`` / ``acc=ego``: SV_acc from the front vehicle's (paper) or the ego's own
  (released code) acceleration.

Writes ``rules_study.csv`` / ``rules_study.md`` under ``--out`` and prints the markdown table.

Usage:
    python benchmarks/rules_study.py --rows 3 --cols 3 --steps 3000 --seeds 0 1 2
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mivecc_env import cli_args
from mivecc_env.config import MiVeCCConfig
from mivecc_env.metrics import batch_summary
from mivecc_env.sim.core import Simulator

READINGS: dict[str, dict] = {
    "sensible/acc=ego": {"end_rule": "sensible", "sv_acc_source": "ego"},
    "sensible/acc=front": {"end_rule": "sensible", "sv_acc_source": "front"},
    "literal/acc=ego": {"end_rule": "literal", "sv_acc_source": "ego"},
    "literal/acc=front": {"end_rule": "literal", "sv_acc_source": "front"},
    "sensible+same_lane/acc=ego": {
        "end_rule": "sensible", "same_lane_rule": True, "sv_acc_source": "ego"
    },
    "sensible+same_lane/acc=front": {
        "end_rule": "sensible", "same_lane_rule": True, "sv_acc_source": "front"
    },
}


def run_one(rows: int, cols: int, density: float, seed: int, steps: int, **overrides) -> dict:
    """Run scheme E for ``steps`` steps and return its episode summary (one environment)."""
    return run_batch(rows, cols, [density], [seed], steps, **overrides)[0]


def run_batch(rows: int, cols: int, densities: list[float], seeds: list[int], steps: int,
              **overrides) -> list[dict]:
    """Run scheme E for every (density, seed) as one batched simulator; returns one episode
    summary per pair (densities outer, seeds inner), each equal to a B = 1 run of that pair."""
    pairs = [(float(d), int(s)) for d in densities for s in seeds]
    cfg = MiVeCCConfig(rows=rows, cols=cols, density_vplh=pairs[0][0], scheme="E", **overrides)
    sim = Simulator(cfg, batch_size=len(pairs), seed=[s for _, s in pairs],
                    densities=[d for d, _ in pairs])
    for _ in range(steps):
        sim.step()
    summary = batch_summary(sim)
    return [{k: float(v[j]) for k, v in summary.items()} for j in range(len(pairs))]


def _row(reading: str, density: float, per_seed: list[dict]) -> dict:
    """One table row: the means and sums over the seeds of one reading and density."""
    mean = {k: float(np.mean([r[k] for r in per_seed])) for k in per_seed[0]}
    return {
        "reading": reading, "density_vplh": density, "seeds": len(per_seed),
        "avg_travel_velocity_mps": mean["avg_travel_velocity_mps"],
        "upper_bound_mps": mean["upper_bound_mps"],
        "collisions_total": int(sum(r["collisions"] for r in per_seed)),
        "collided_vehicles_total": int(sum(r["collided_vehicles"] for r in per_seed)),
        "arrived_total": int(sum(r["arrived"] for r in per_seed)),
        "throughput_mean": mean["throughput"],
        "backlog_mean": mean["backlog"],
        **near_miss_columns(per_seed),
    }


def near_miss_columns(per_seed: list[dict]) -> dict:
    """Released-style velocity (mean over seeds) and near-miss figures over the seeds: the
    smallest minima, the mean 1st-percentile TTC, the total PET samples below 1 s."""
    return {
        "released_velocity_mps": float(np.mean([r["released_velocity_mps"] for r in per_seed])),
        "min_ttc_s": float(min(r["min_ttc_s"] for r in per_seed)),
        "ttc_p1_s": float(np.mean([r["ttc_p1_s"] for r in per_seed])),
        "min_pet_s": float(min(r["min_pet_s"] for r in per_seed)),
        "pet_under_1s_total": int(sum(r["pet_under_1s"] for r in per_seed)),
        "min_distance_m": float(min(r["min_distance_m"] for r in per_seed)),
    }


def main(argv: list[str] | None = None) -> list[dict]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=cli_args.count(1), default=3)
    parser.add_argument("--cols", type=cli_args.count(1), default=3)
    parser.add_argument("--densities", type=cli_args.density, nargs="+",
                        default=[300, 900, 1500, 2100])
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=cli_args.count(1), default=3000)
    parser.add_argument("--readings", nargs="+", default=list(READINGS), choices=list(READINGS))
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/rules_study"))
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    for option in ("seeds", "densities"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))

    rows = []
    for reading in tqdm(args.readings, desc="rules study"):
        # every density and seed of a reading as one batch of environments
        runs = run_batch(args.rows, args.cols, args.densities, args.seeds, args.steps,
                         **READINGS[reading])
        n = len(args.seeds)
        for i, density in enumerate(args.densities):
            rows.append(_row(reading, density, runs[i * n:(i + 1) * n]))

    with open(args.out / "rules_study.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    header = ("| reading | veh/lane/h | avg travel velocity [m/s] | upper bound [m/s] | "
              "collisions (sum over seeds) | vehicles arrived | collisions per 1000 arrived | "
              "released-style velocity [m/s] | min TTC [s] | TTC 1st pct [s] | min PET [s] | "
              "PET < 1 s | min distance [m] |")
    lines = [header, "|" + "---|" * 13]
    for r in rows:
        per_k = 1000.0 * r["collisions_total"] / max(r["arrived_total"], 1)
        lines.append(
            f"| {r['reading']} | {r['density_vplh']:.0f} | {r['avg_travel_velocity_mps']:.3f} | "
            f"{r['upper_bound_mps']:.3f} | {r['collisions_total']} | {r['arrived_total']} | "
            f"{per_k:.1f} | {r['released_velocity_mps']:.3f} | {r['min_ttc_s']:.3f} | "
            f"{r['ttc_p1_s']:.2f} | {r['min_pet_s']:.3f} | {r['pet_under_1s_total']} | "
            f"{r['min_distance_m']:.3f} |"
        )
    table = "\n".join(lines)
    cmd = ("python benchmarks/rules_study.py --rows {} --cols {} --steps {} --seeds {}".format(
        args.rows, args.cols, args.steps, " ".join(map(str, args.seeds))))
    (args.out / "rules_study.md").write_text(f"Command: `{cmd}`\n\n{table}\n")
    print(table)
    return rows


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
