"""How finely does the paper table's setting tell a coordinator from its +3 ceiling?

Issue 10 judges each learned coordinator "at or above its constant-action ceiling" from the
gains ``benchmarks/paper_targets.py`` reads off the paper table (3 seeds x 3000 steps, to 0.01
points). This script measures what that judgement can resolve. It runs the ceiling (every
column of the coordinator always +3 m/s^2) beside coordinators that are constant too but a
hair lower, +3 minus each ``--deltas`` value [m/s^2] (``ulp``: one float32 unit in the last
place below 3, 2.4e-7 m/s^2), and the model's shipped policy of that kind, each over the
same baseline (MiVeCC-E for the edge; MiVeCC-EE with the model's shipped edge for the cloud,
which decides every ``--cloud-period`` steps in every run). Per density it writes each one's
gain over the baseline [%] and its difference from the ceiling's gain [points], and for the
shipped policy the largest shortfall of its actions from +3 [m/s^2] over every real column it
set.

Every run calls its policies once per environment (``evaluate_batch(...,
stack_policies=False)``), so no result depends on the batch; runs use one torch thread each.

Output (``--out``): ``ceiling_resolution.md`` (the tables and the command) and
``ceiling_resolution.csv`` (one row per variant and density).

Usage (3x3, released model, shield; about 4 min with two workers here; ``docs/training.md``,
"How finely the table judges a coordinator against its ceiling"):
    python benchmarks/ceiling_resolution.py --kind cloud --model released \
        --set safety_shield=true --out runs/s33/resolution_cloud
"""

from __future__ import annotations

import csv
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from paper_table import DENSITIES, config_overrides

from mivecc_env import cli_args
from mivecc_env.processes import map_jobs

#: Config fields this script's own options set (not accepted by --set).
OWN_FIELDS = {"rows": "--grid", "cols": "--grid", "density_vplh": "--densities",
              "scheme": "--kind", "max_steps": "--steps", "model": "--model",
              "cloud_period": "--cloud-period"}
#: One float32 unit in the last place below +3 [m/s^2] (the ceiling's action,
#: ``mivecc_agents.policies.CEILING_ACCEL_MPS2``, imported with torch where it is used).
ULP_BELOW_3 = float(3.0 - np.nextafter(np.float32(3.0), np.float32(0.0)))


def delta(text: str) -> float:
    """Argument type: a shortfall below +3 in (0, 6] m/s^2, or ``ulp``."""
    if text == "ulp":
        return ULP_BELOW_3
    return cli_args.number(0.0, 6.0, low_ok=False)(text)


def _run(job: tuple[str, str, dict[str, Any]]) -> tuple[str, list[dict[str, Any]], float]:
    """One variant on every density and seed as one batch: (variant, results, the largest
    shortfall of the variant's coordinator actions from +3 [m/s^2], NaN for a constant)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch: one thread per worker
    import torch

    from mivecc_agents.evaluation import evaluate_batch
    from mivecc_agents.policies import CEILING_ACCEL_MPS2, constant_policy, pretrained_policies
    from mivecc_agents.train_eval import KIND_SCHEMES
    from mivecc_env.config import from_overrides

    torch.set_num_threads(1)
    variant, kind, a = job
    config = from_overrides(model=a["model"], **a["overrides"])
    shipped = pretrained_policies(a["model"], safety_shield=config.safety_shield)
    k = getattr(config, f"k_{kind}")
    policies: dict[str, Any] = {} if kind == "edge" else {"edge": shipped["edge"]}
    shortfall = [0.0]
    if variant == "shipped":
        policies[kind] = shipped[kind]
    elif variant != "baseline":
        policies[kind] = constant_policy(kind, float(variant), k)

    def on_step(before: Any, edge: Any, cloud: Any, _after: Any) -> None:
        acts, mask = (edge, before.edge_mask) if kind == "edge" else (cloud, before.cloud_mask)
        real = (mask > 0) & np.isfinite(acts)
        if real.any():
            shortfall[0] = max(shortfall[0], float(np.max(CEILING_ACCEL_MPS2 - acts[real])))

    scheme = KIND_SCHEMES[kind][1 if variant == "baseline" else 0]
    extra = {"cloud_period": a["cloud_period"]} if scheme == "EEC" else {}
    results = evaluate_batch(scheme, a["rows"], a["cols"], a["densities"], a["steps"],
                             a["seeds"], policies=policies, progress=False, warn=False,
                             stack_policies=False, on_step=on_step if variant == "shipped"
                             else None, model=a["model"], **a["overrides"], **extra)
    return variant, results, shortfall[0] if variant == "shipped" else float("nan")


def main(argv: Sequence[str] | None = None) -> Path:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=("edge", "cloud"), required=True)
    parser.add_argument("--model", choices=("paper", "released"), default="paper")
    parser.add_argument("--grid", type=cli_args.grid, default=(3, 3))
    parser.add_argument("--densities", type=cli_args.density, nargs="+", default=list(DENSITIES))
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=cli_args.count(1), default=3000)
    parser.add_argument("--deltas", type=delta, nargs="+", default=[ULP_BELOW_3, 1e-4, 1e-2],
                        help="shortfalls below +3 of the other constant coordinators [m/s^2] "
                        "('ulp': 2.4e-7)")
    parser.add_argument("--cloud-period", type=cli_args.count(1), default=10,
                        help="steps between cloud decisions (every cloud run)")
    parser.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", default=[],
                        help="other config fields for every run, e.g. safety_shield=true")
    parser.add_argument("--workers", type=cli_args.count(1), default=2)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/ceiling_resolution"))
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    for option in ("seeds", "densities", "deltas"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))
    overrides = config_overrides(args.set_items, args.model, OWN_FIELDS)
    from mivecc_agents.policies import CEILING_ACCEL_MPS2

    common = dict(rows=args.grid[0], cols=args.grid[1], densities=list(args.densities),
                  steps=args.steps, seeds=list(args.seeds), model=args.model,
                  cloud_period=args.cloud_period, overrides=overrides)
    constants = [repr(CEILING_ACCEL_MPS2)] + [
        repr(float(np.float32(CEILING_ACCEL_MPS2 - d))) for d in args.deltas]
    jobs = [(v, args.kind, common) for v in ["baseline", "shipped", *constants]]
    done = map_jobs(_run, jobs, args.workers, "runs")
    return write_report(done, args, argv)


def write_report(done: list[tuple[str, list[dict[str, Any]], float]], args: Any,
                 argv: Sequence[str] | None) -> Path:
    """``ceiling_resolution.md`` and ``.csv`` from the runs (module docstring)."""
    from mivecc_agents.policies import CEILING_ACCEL_MPS2
    from mivecc_agents.train_eval import gain_pct, headline_metric

    metric = headline_metric(args.model)
    velocity = {v: {d: float(np.mean([r[metric] for r in res if r["density"] == float(d)]))
                    for d in args.densities} for v, res, _ in done}
    shortfall = next(s for v, _, s in done if v == "shipped")
    variants = [v for v, _, _ in done if v != "baseline"]
    gains = {v: {d: gain_pct(velocity[v][d], velocity["baseline"][d]) for d in args.densities}
             for v in variants}
    ceiling = repr(CEILING_ACCEL_MPS2)
    rows = [{"variant": v, "density": d, "velocity_mps": velocity[v][d],
             "baseline_mps": velocity["baseline"][d], "gain_pct": gains[v][d],
             "minus_ceiling_points": round(gains[v][d], 2) - round(gains[ceiling][d], 2)}
            for v in variants for d in args.densities]
    with open(args.out / "ceiling_resolution.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    base = "MiVeCC-E" if args.kind == "edge" else "MiVeCC-EE with the shipped edge"
    label = {v: ("shipped " + args.kind if v == "shipped" else f"constant {float(v):.7f}")
             for v in variants}
    head = " | ".join(f"{d:g}" for d in args.densities)
    lines = [f"Command: `python benchmarks/ceiling_resolution.py "
             f"{' '.join(argv if argv is not None else sys.argv[1:])}`", "",
             f"{args.kind}, model {args.model}, {args.grid[0]}x{args.grid[1]}, seeds "
             f"{', '.join(map(str, args.seeds))} x {args.steps} steps; {metric}; gain over "
             f"{base} [%], as paper_targets.py rounds it (0.01 points). The shipped "
             f"{args.kind}'s actions fall short of +3 by at most {shortfall:.3g} m/s^2.", "",
             f"| gain over the baseline [%] | {head} |",
             "|---|" + "---|" * len(args.densities)]
    lines += [f"| {label[v]} | " + " | ".join(f"{gains[v][d]:+.2f}" for d in args.densities)
              + " |" for v in variants]
    lines += ["", f"| minus the +3 ceiling's gain [points] | {head} |",
              "|---|" + "---|" * len(args.densities)]
    lines += [f"| {label[v]} | " + " | ".join(
        f"{r['minus_ceiling_points']:+.2f}" for r in rows if r["variant"] == v) + " |"
        for v in variants if v != ceiling]
    path = args.out / "ceiling_resolution.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(path.read_text(encoding="utf-8"))
    return path


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
