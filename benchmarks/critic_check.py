"""Does a trained critic know that its actor could do better? (edge or cloud)

The stage-II reward ranks constant clouds like the metric does and the constant +3 m/s^2
cloud is best (``benchmarks/cloud_reward_check.py``), yet the learned clouds act far below
it; the learned edges stay below the constant +3 edge too. This check asks the checkpoint's
own critic. For ``--kind cloud`` it runs MiVeCC-EEC with the model's shipped edge and the
checkpoint's cloud, for ``--kind edge`` MiVeCC-EE with the checkpoint's edge (every (density,
seed) pair as one batch). It keeps the coordinator's observations (every node's graph with a
decision vehicle) every ``--every`` steps after ``--skip`` fill-up steps, and evaluates the
critic in those states at:

* the actor's action ``a``;
* ``a`` shifted by +-``--shift`` m/s^2 in every real column (clamped to [-3, 3]);
* constant actions (``--constants``).

For each it prints the mean of ``Q(s, x) - Q(s, a)`` and the share of states where it is
positive. A critic whose ``Q(s, +3) - Q(s, a)`` is positive in most states points its actor
towards +3 (the actor's step size then limits); one near zero or mixed has not resolved the
effect of the action (the critic limits). The deterministic policy gradient the actor
follows is the slope ``dQ/da``; its component along "all columns up" is printed too, and so
are the actor's mean action and the shares of its actions at either bound (within
:data:`AT_BOUND_MPS2`): a saturated actor sits at the bounds, and then what separates it from a
constant +3 coordinator is its share at -3, not the size of its positive actions.

``benchmarks/cloud_critic_check.py`` is this script with ``--kind cloud`` (its earlier name;
the committed results cite it).

Usage (about 10 s to 1 min on an idle 2-core machine):
    python benchmarks/critic_check.py --kind edge --model released --out benchmarks/results
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

from mivecc_agents.checkpoints import load_checkpoint, network_variant
from mivecc_agents.evaluation import evaluate_batch
from mivecc_agents.learner import SATURATED_Z
from mivecc_agents.networks import critic_members_in, make_critic_net
from mivecc_agents.policies import load_policy, pretrained_path, pretrained_policies
from mivecc_env import cli_args
from mivecc_env.config import from_overrides

#: Config fields this script's own options set (not accepted by --set).
OWN_FIELDS = {"rows": "--rows", "cols": "--cols", "density_vplh": "--densities",
              "scheme": "--kind", "max_steps": "--steps", "model": "--model"}

ACTION_BOUND_MPS2 = 3.0
#: An action this close to a bound counts as at the bound [m/s^2].
AT_BOUND_MPS2 = 0.01


def at_bound(actions: np.ndarray, sign: float) -> np.ndarray:
    """Which ``actions`` [m/s^2] lie within :data:`AT_BOUND_MPS2` of the bound ``sign * 3``."""
    return np.abs(actions - sign * ACTION_BOUND_MPS2) <= AT_BOUND_MPS2


#: The scheme each coordinator kind's states are collected under.
SCHEME = {"edge": "EE", "cloud": "EEC"}


def collect_states(
    kind: str, model: str, rows: int, cols: int, densities: Sequence[float],
    seeds: Sequence[int], steps: int, skip: int, every: int, path: Path,
    overrides: dict[str, Any] | None = None,
) -> tuple[np.ndarray, np.ndarray, int | None]:
    """Observations (n, K, K, 3) and masks (n, K) of every node of ``kind`` with a decision
    vehicle, kept every ``every`` steps from step ``skip`` on, under the checkpoint's policy
    (a cloud: over the model's shipped edge, deciding at its training ``cloud_period``, also
    returned; an edge: MiVeCC-EE, period ``None``), with the config ``overrides`` (``--set``)."""
    overrides = overrides or {}
    shield = from_overrides(model=model, **overrides).safety_shield
    policies = ({"edge": pretrained_policies(model, safety_shield=shield)["edge"]}
                if kind == "cloud" else {})
    policies[kind] = load_policy(path, expected_kind=kind)
    obs: list[np.ndarray] = []
    masks: list[np.ndarray] = []
    t = [0]

    def record(before: Any, _edge: Any, _cloud: Any, _after: Any) -> None:
        if t[0] >= skip and (t[0] - skip) % every == 0:
            o = getattr(before, f"{kind}_obs")
            m = getattr(before, f"{kind}_mask")
            o = o.reshape(-1, *o.shape[-3:])  # (B, [n_edge,] K, K, 3) -> rows
            m = m.reshape(-1, m.shape[-1])
            real = m.sum(axis=1) > 0
            obs.append(np.array(o[real], dtype=np.float32))
            masks.append(np.array(m[real], dtype=np.float32))
        t[0] += 1

    results = evaluate_batch(SCHEME[kind], rows, cols, densities, steps, seeds,
                             policies=policies, progress=False, warn=False, on_step=record,
                             stack_policies=True,  # as when its documented outputs were made
                             model=model, **overrides)
    period = int(results[0]["cloud_period"]) if kind == "cloud" else None
    return np.concatenate(obs), np.concatenate(masks), period


def critic_gaps(
    kind: str, path: Path, obs: np.ndarray, mask: np.ndarray, shift: float,
    constants: Sequence[float],
) -> list[dict[str, Any]]:
    """``Q(s, x) - Q(s, a)`` statistics for each probe action ``x`` (see the module doc)."""
    ckpt = load_checkpoint(path, expected_kind=kind)
    variant = network_variant(ckpt)
    with torch.random.fork_rng(devices=[]):
        critic = make_critic_net(kind, variant=variant,
                                 members=critic_members_in(ckpt["critic"]))
    critic.load_state_dict(ckpt["critic"])
    critic.eval()
    actor = load_policy(path, expected_kind=kind)
    o = torch.as_tensor(obs)
    m = torch.as_tensor(mask)
    a = torch.as_tensor(actor(obs, mask))
    bound = ACTION_BOUND_MPS2
    probes = [(f"a {'+' if s > 0 else '-'} {abs(s):g}", (a + s).clamp(-bound, bound))
              for s in (shift, -shift)]
    probes += [(f"constant {c:+g}", torch.full_like(a, c)) for c in constants]
    rows = []
    with torch.no_grad():
        q_a = critic(o, a, m).mean(-1)
        for name, x in probes:
            gap = (critic(o, x * m, m).mean(-1) - q_a).numpy()
            rows.append({"probe": name, "mean_gap": float(gap.mean()),
                         "share_positive": float((gap > 0).mean())})
    a_var = a.clone().requires_grad_(True)
    q = critic(o, a_var, m).mean(-1).sum()
    (grad,) = torch.autograd.grad(q, a_var)
    slope_up = (grad * m).sum(dim=-1).numpy()  # dQ/dc of a + c (all real columns)
    rows.append({"probe": "slope dQ/dc of a + c*1 [1/(m/s^2)]", "mean_gap": float(slope_up.mean()),
                 "share_positive": float((slope_up > 0).mean())})
    real = mask > 0
    actions = a.numpy()[real]
    rows.append({"probe": "actor: mean action [m/s^2]", "mean_gap": float(actions.mean()),
                 "share_positive": float((actions > 0).mean())})
    # how the actions spread: at a bound (a saturated, bang-bang actor) or between
    for sign, name in ((1.0, "+3"), (-1.0, "-3")):
        share = float(at_bound(actions, sign).mean())
        rows.append({"probe": f"actor: share of actions within {AT_BOUND_MPS2:g} of {name}",
                     "mean_gap": share, "share_positive": share})
    rows.append({"probe": "critic: mean Q(s, a)", "mean_gap": float(q_a.mean()),
                 "share_positive": float((q_a > 0).float().mean())})
    return rows


def actor_columns(kind: str, path: Path, obs: np.ndarray, mask: np.ndarray) -> dict[str, Any]:
    """How the checkpoint's actor acts per column (a cloud's pick rank, an edge's decision
    slot) over the kept states.

    Returns a dict: ``saturated_share`` (share of the real columns' pre-tanh outputs ``z``
    with ``|z| >`` :data:`SATURATED_Z`, where the action's gradient ``3 (1 - tanh(z)^2)`` is
    below 2e-4), ``median_abs_z``, and the columns (0-based, among those real in some state)
    whose action is within :data:`AT_BOUND_MPS2` of +3 in every state (``always_plus3``), of
    -3 in every state (``always_minus3``), or neither (``state_dependent``).
    """
    net = load_policy(path, expected_kind=kind).net
    with torch.no_grad():
        z = net.preactivation(torch.as_tensor(obs)).numpy()
    action = ACTION_BOUND_MPS2 * np.tanh(z)
    real = mask > 0
    columns: dict[str, list[int]] = {"always_plus3": [], "always_minus3": [],
                                     "state_dependent": []}
    for j in np.flatnonzero(real.any(axis=0)):
        a_j = action[real[:, j], j]
        if np.all(at_bound(a_j, 1.0)):
            columns["always_plus3"].append(int(j))
        elif np.all(at_bound(a_j, -1.0)):
            columns["always_minus3"].append(int(j))
        else:
            columns["state_dependent"].append(int(j))
    return {"saturated_share": float((np.abs(z[real]) > SATURATED_Z).mean()),
            "median_abs_z": float(np.median(np.abs(z[real]))), **columns}


def main(argv: Sequence[str] | None = None, *, fixed_kind: str | None = None,
         prog: str = "benchmarks/critic_check.py") -> list[dict[str, Any]]:
    """Run the check; ``fixed_kind`` / ``prog``: a script that checks one kind only (no
    ``--kind`` option; its name in the written command)."""
    parser = cli_args.Parser(prog=prog, description=__doc__.splitlines()[0])
    if fixed_kind is None:
        parser.add_argument("--kind", choices=("edge", "cloud"), required=True)
    parser.add_argument("--model", choices=("paper", "released"), default="released")
    for kind in ("edge", "cloud") if fixed_kind is None else (fixed_kind,):
        parser.add_argument(f"--{kind}", type=Path, default=None,
                            help=f"{kind} checkpoint (actor and critic) to check; default: the "
                                 "model's shipped one")
    parser.add_argument("--rows", type=cli_args.count(1), default=3)
    parser.add_argument("--cols", type=cli_args.count(1), default=3)
    parser.add_argument("--densities", type=cli_args.density, nargs="+", default=[1500.0, 2100.0])
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1])
    parser.add_argument("--steps", type=cli_args.count(1), default=1500)
    parser.add_argument("--skip", type=cli_args.count(0), default=500,
                        help="fill-up steps before states are kept")
    parser.add_argument("--every", type=cli_args.count(1), default=10,
                        help="keep a state every N steps")
    parser.add_argument("--shift", type=cli_args.number(0.0, low_ok=False), default=1.0,
                        help="shift of the actor's action in every column [m/s^2]")
    parser.add_argument("--constants", type=cli_args.number(-3.0, 3.0), nargs="*",
                        default=[-3.0, 0.0, 3.0],
                        help="constant probe actions [m/s^2]")
    parser.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", default=[],
                        help="other config fields, e.g. safety_shield=true (as paper_table.py)")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = parser.parse_args(argv)
    overrides = config_overrides(args.set_items, args.model, OWN_FIELDS)
    cli_args.writable_dir("--out", args.out)
    kind = fixed_kind or args.kind
    if not 0 <= args.skip < args.steps:
        parser.error(f"--skip: must be in [0, --steps - 1] = [0, {args.steps - 1}], "
                     f"got {args.skip}")
    if args.every < 1:
        parser.error(f"--every: must be >= 1, got {args.every}")
    if not 0 < args.shift <= 2 * ACTION_BOUND_MPS2:
        parser.error(f"--shift: must be in (0, 6] m/s^2, got {args.shift}")
    bad = [c for c in args.constants if not -3.0 <= c <= 3.0]
    if bad:
        parser.error(f"--constants: each must be in [-3, 3] m/s^2, got {bad}")
    given = getattr(args, kind)
    other = "cloud" if kind == "edge" else "edge"
    if fixed_kind is None and getattr(args, other) is not None:
        parser.error(f"--{other}: checks --kind {other} only; this run checks --kind {kind}")
    shield = from_overrides(model=args.model, **overrides).safety_shield
    path = given if given is not None else pretrained_path(kind, args.model, shield)
    if path is None:
        parser.error(f"--{kind}: no shipped {kind} for model {args.model!r}; name a checkpoint")
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    obs, mask, period = collect_states(kind, args.model, args.rows, args.cols, args.densities,
                                       args.seeds, args.steps, args.skip, args.every, path,
                                       overrides)
    rows = critic_gaps(kind, path, obs, mask, args.shift, args.constants)
    cols = actor_columns(kind, path, obs, mask)
    of_period = "" if period is None else f" (cloud_period {period})"
    print(f"{len(obs)} states of {path}{of_period}, {time.perf_counter() - t0:.0f} s")
    for r in rows:
        print(f"  {r['probe']:44s} mean {r['mean_gap']:+.5f}  positive in "
              f"{100 * r['share_positive']:.0f} %")
    col_lines = [
        f"saturated pre-activations (|z| > {SATURATED_Z:g}): {100 * cols['saturated_share']:.1f} %"
        f", median |z| {cols['median_abs_z']:.1f}",
        *(f"{name} ({len(cols[name])} columns): {' '.join(map(str, cols[name])) or '-'}"
          for name in ("always_plus3", "always_minus3", "state_dependent")),
    ]
    for line in col_lines:
        print(f"  actor {line}")
    out = args.out / f"{kind}_critic_check_{args.model}.md"
    column = "pick rank" if kind == "cloud" else "decision slot"
    lines = [
        f"Command: `python {prog}" + ("" if fixed_kind else f" --kind {kind}")
        + f" --model {args.model}"
        + (f" --{kind} {given}" if given is not None else "")
        + f" --rows {args.rows} --cols {args.cols} --densities "
        f"{' '.join(f'{d:g}' for d in args.densities)} --seeds "
        f"{' '.join(map(str, args.seeds))} --steps {args.steps} --skip {args.skip} --every "
        f"{args.every} --shift {args.shift:g} --constants "
        f"{' '.join(f'{c:g}' for c in args.constants)}"
        + (f" --set {' '.join(args.set_items)}" if args.set_items else "") + "`",
        "",
        f"{len(obs)} {kind} states{of_period} of "
        + (f"`{given}`." if given is not None else f"the shipped {args.model}-model {kind}."),
        "",
        "| probe x | mean Q(s, x) - Q(s, a) (or the value named) | share of states > 0 |",
        "|---|---|---|",
    ]
    lines += [f"| {r['probe']} | {r['mean_gap']:+.5f} | {100 * r['share_positive']:.0f} % |"
              for r in rows]
    lines += ["", f"The actor per column ({column}, 0-based; at a bound: within "
              f"{AT_BOUND_MPS2:g} m/s^2 in every state):", ""]
    lines += [f"- {line}" for line in col_lines]
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")
    return rows


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
