"""Does one call on the stacked batch give each environment's own actions, on real graphs?

``mivecc_agents.evaluation.stacking_is_exact`` decides before an evaluation, on random graphs,
whether a policy may be called once on all environments' graphs stacked. This script checks
the decision on the graphs a real run meets: it runs one batch (every density x seed, the
policy called once per environment, so the trajectories are the single runs') and at every
step calls the policy once more on the stacked graphs, counting the environment-steps whose
actions differ in any bit (and the node, column and size of each difference).

Usage (the shipped released shield edge, 3x3; ``docs/training.md``, "The check is a sample,
not a proof"; about 1 min 20 s with two threads here):
    python benchmarks/stacking_audit.py --kind edge --model released --set safety_shield=true \
        --threads 2 --out runs/s33/stacking_audit_t2
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from paper_table import config_overrides

from mivecc_env import cli_args

#: Config fields this script's own options set (not accepted by --set).
OWN_FIELDS = {"rows": "--grid", "cols": "--grid", "density_vplh": "--densities",
              "scheme": "--kind", "max_steps": "--steps", "model": "--model"}


def main(argv: Sequence[str] | None = None) -> Path:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=("edge",), default="edge",
                        help="the coordinator audited (MiVeCC-EE with the shipped edge)")
    parser.add_argument("--model", choices=("paper", "released"), default="paper")
    parser.add_argument("--grid", type=cli_args.grid, default=(3, 3))
    parser.add_argument("--densities", type=cli_args.density, nargs="+", default=[300, 2100])
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=cli_args.count(1), default=1500)
    parser.add_argument("--threads", type=cli_args.count(1), default=1,
                        help="torch intra-op threads of the policy calls")
    parser.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", default=[],
                        help="other config fields, e.g. safety_shield=true")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/stacking_audit"))
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    for option in ("seeds", "densities"):
        cli_args.check_distinct(f"--{option}", getattr(args, option))
    overrides = config_overrides(args.set_items, args.model, OWN_FIELDS)

    import torch

    from mivecc_agents.evaluation import evaluate_batch, stacking_is_exact
    from mivecc_agents.policies import pretrained_policies
    from mivecc_env.config import from_overrides

    torch.set_num_threads(args.threads)
    config = from_overrides(model=args.model, **overrides)
    edge = pretrained_policies(args.model, safety_shield=config.safety_shield)["edge"]
    differences: list[dict[str, Any]] = []
    counted = [0]  # environment-steps checked
    step_no = [-1]  # the step being checked, from 0

    def on_step(before: Any, _edge: Any, _cloud: Any, _after: Any) -> None:
        obs, mask = before.edge_obs, before.edge_mask
        b, n, k = mask.shape
        step_no[0] += 1
        stacked = np.asarray(edge(obs.reshape(-1, k, k, 3), mask.reshape(-1, k))).reshape(b, n, k)
        for env in range(b):
            own = np.asarray(edge(obs[env], mask[env]))
            counted[0] += 1
            for node, col in np.argwhere(own != stacked[env]):
                differences.append({"step": step_no[0], "env": env,
                                    "node": int(node), "column": int(col),
                                    "real_column": bool(mask[env, node, col] > 0),
                                    "abs_diff_mps2": float(abs(own[node, col]
                                                               - stacked[env, node, col]))})

    rows, cols = args.grid
    evaluate_batch("EE", rows, cols, list(args.densities), args.steps, list(args.seeds),
                   policies={"edge": edge}, progress=True, warn=False, stack_policies=False,
                   on_step=on_step, model=args.model, **overrides)
    b = len(args.densities) * len(args.seeds)
    steps_with = sorted({(d["step"], d["env"]) for d in differences})
    report = {
        "command": "python benchmarks/stacking_audit.py "
                   + " ".join(argv if argv is not None else sys.argv[1:]),
        "threads": args.threads, "environments": b, "steps": args.steps,
        "environment_steps": counted[0],
        "random_graph_check_says_exact": stacking_is_exact(edge, b, rows * cols, config.k_edge),
        "environment_steps_that_differ": len(steps_with),
        "first": [{"step": s, "env": e} for s, e in steps_with[:5]],
        "nodes": sorted({d["node"] for d in differences}),
        "largest_difference_mps2": max((d["abs_diff_mps2"] for d in differences), default=0.0),
        "all_in_real_columns": all(d["real_column"] for d in differences),
    }
    path = args.out / "stacking_audit.json"
    path.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(json.dumps(report, indent=2))
    return path


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
