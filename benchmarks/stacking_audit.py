"""Does one call on the stacked batch give each environment's own actions, on real graphs?

``mivecc_agents.evaluation.stacking_is_exact`` decides before an evaluation, on random graphs,
whether a policy may be called once on all environments' graphs stacked. This script checks
the decision on the graphs a real run meets: it runs one batch (every density x seed, every
policy called once per environment, so the trajectories are the single runs') and at every
step calls the audited policy once more on the stacked graphs of the environments it acts in,
counting the environment-steps whose actions differ in any bit (and the node, column and size
of each difference). ``--kind edge`` audits the shipped edge in MiVeCC-EE; ``--kind cloud``
the shipped cloud in MiVeCC-EEC (with the shipped edge, on the cloud's decision steps).

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

#: The scheme each audited kind runs in.
SCHEME = {"edge": "EE", "cloud": "EEC"}


def main(argv: Sequence[str] | None = None) -> Path:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=tuple(SCHEME), default="edge",
                        help="the coordinator audited: edge (in MiVeCC-EE) or cloud (in "
                             "MiVeCC-EEC, with the shipped edge)")
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
    from mivecc_agents.policies import PRETRAINED_DIR, pretrained_policies
    from mivecc_env.config import from_overrides

    torch.set_num_threads(args.threads)
    config = from_overrides(model=args.model, **overrides)
    policies = pretrained_policies(args.model, safety_shield=config.safety_shield)
    if args.kind == "edge":
        policies.pop("cloud", None)
    audited = policies[args.kind]
    differences: list[dict[str, Any]] = []
    counted = [0]  # environment-steps checked
    step_no = [-1]  # the step being checked, from 0

    def on_step(before: Any, edge_actions: Any, cloud_actions: Any, _after: Any) -> None:
        step_no[0] += 1
        if args.kind == "edge":
            obs, mask = before.edge_obs, before.edge_mask
            envs = np.arange(mask.shape[0])
        else:  # the cloud's graphs; only the environments whose cloud decides on this step
            b = cloud_actions.shape[0]
            obs = before.cloud_obs.reshape(b, -1, *before.cloud_obs.shape[-3:])
            mask = before.cloud_mask.reshape(b, -1, before.cloud_mask.shape[-1])
            envs = np.flatnonzero(~np.isnan(cloud_actions.reshape(b, -1)).all(axis=1))
        if envs.size == 0:
            return
        n, k = mask.shape[1:]
        stacked = np.asarray(audited(obs[envs].reshape(-1, k, k, 3),
                                     mask[envs].reshape(-1, k))).reshape(envs.size, n, k)
        for row, env in enumerate(envs):
            own = np.asarray(audited(obs[env], mask[env]))
            counted[0] += 1
            for node, col in np.argwhere(own != stacked[row]):
                differences.append({"step": step_no[0], "env": int(env),
                                    "node": int(node), "column": int(col),
                                    "real_column": bool(mask[env, node, col] > 0),
                                    "abs_diff_mps2": float(abs(own[node, col]
                                                               - stacked[row, node, col]))})

    rows, cols = args.grid
    evaluate_batch(SCHEME[args.kind], rows, cols, list(args.densities), args.steps,
                   list(args.seeds), policies=policies, progress=True, warn=False,
                   stack_policies=False, on_step=on_step, model=args.model, **overrides)
    b = len(args.densities) * len(args.seeds)
    n_graphs = rows * cols if args.kind == "edge" else config.n_cloud_graphs
    steps_with = sorted({(d["step"], d["env"]) for d in differences})
    report = {
        "command": "python benchmarks/stacking_audit.py "
                   + " ".join(argv if argv is not None else sys.argv[1:]),
        "kind": args.kind,
        "policy": Path(audited.checkpoint).relative_to(PRETRAINED_DIR.parents[1]).as_posix(),
        "threads": args.threads, "environments": b, "steps": args.steps,
        "environment_steps": counted[0],
        "random_graph_check_says_exact": stacking_is_exact(
            audited, b, n_graphs, getattr(config, f"k_{args.kind}")),
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
