"""Is there headroom above the constant +3 coordinator? A direct search says.

The learned coordinators end at about the constant-action ceilings (edge always +3, cloud
always +3; ``benchmarks/paper_table.py``), and issue 10 asks for each at or above its ceiling.
Whether any coordinator beats the ceiling is a question about the control problem, not about
DDPG, and this script asks it without a critic: a cross-entropy search (Rubinstein 1999) over a
small state-feedback policy family that contains the ceiling, scored by the traffic metric
itself.

Policy family (one parameter vector ``theta`` shared by every column of every node):
``a_j = 3 tanh(theta . x_j)`` [m/s^2], where ``x_j`` holds column j's decision vehicle (row 0
of the state graph: position to its next conflict point, velocity, acceleration), its nearest
reference vehicle (row 1: relative position, velocity, acceleration) and a bias 1. The
ceiling is ``theta = (0, ..., 0, +inf)``; the search starts next to it (bias 2: +2.9 m/s^2).

Score of a policy: the share of the ceiling's gain it realises, ``(v - v_base) / (v_ceil -
v_base)`` [%] averaged over the search's densities and seeds (v: released-style velocity under
``--model released``, else the average travel velocity; base: MiVeCC-E for the edge,
MiVeCC-EE with the model's shipped edge for the cloud). Above 100 % beats the ceiling. The
search uses evaluation seeds from 1000 on; the policy it ends with (its mean) and the best one
it evaluated are then run on the paper table's setting (``--table-seeds``, every density) with
the strict collision events of each cell.

Every candidate of an iteration runs as one environment of a single batch (same seeds,
densities and steps for all), so an iteration costs one batch of ``population x densities x
seeds`` environments; the environments are independent, so each candidate's trajectory is the
one it would have alone.

Usage (3x3, released model, safety shield; 2-7 min for the edge, 5-11 min for the cloud here,
beside another run; `docs/training.md`, "Is there headroom above the constant +3 coordinators?"):
    python benchmarks/headroom_search.py --kind edge --model released --set safety_shield=true
"""

from __future__ import annotations

import csv
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from paper_table import DENSITIES, config_overrides

from mivecc_agents.networks import ACTION_SCALE_MPS2
from mivecc_agents.policies import Policy, pretrained_policies
from mivecc_agents.train_eval import KIND_SCHEMES, ceiling_share_pct, gain_pct, headline_metric
from mivecc_env import cli_args
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.config import from_overrides

#: Config fields this script's own options set (not accepted by --set).
OWN_FIELDS = {"rows": "--grid", "cols": "--grid", "density_vplh": "--densities",
              "scheme": "--kind", "max_steps": "--steps", "model": "--model",
              "cloud_period": "--cloud-period"}

FEATURES = ("own position", "own velocity", "own acceleration", "reference position",
            "reference velocity", "reference acceleration", "bias")
#: Bias of the search's starting mean: 3 tanh(2) = +2.89 m/s^2 in every column.
START_BIAS = 2.0
#: The ceiling in this family: tanh(30) is 1.0 in float64, so every action is exactly +3.
CEILING_BIAS = 30.0
#: Lower bound of the search's per-parameter standard deviation (keeps it exploring).
SIGMA_FLOOR = 0.05


def column_features(obs: np.ndarray) -> np.ndarray:
    """(..., K, K, 3) state graphs -> (..., K, 7) features of each column (``FEATURES``)."""
    rows01 = np.concatenate([obs[..., 0, :, :], obs[..., 1, :, :]], axis=-1)
    return np.concatenate([rows01, np.ones((*rows01.shape[:-1], 1), rows01.dtype)], axis=-1)


def linear_actions(obs: np.ndarray, mask: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Actions [m/s^2] of the policy family for a batch: ``obs`` (B, ..., K, K, 3), ``mask``
    (B, ..., K), ``theta`` (B, 7), one parameter vector per environment; 0 in padded
    columns."""
    x = column_features(obs.astype(np.float64))
    th = theta.reshape(theta.shape[0], *([1] * (x.ndim - 2)), theta.shape[1])
    return ACTION_SCALE_MPS2 * np.tanh((x * th).sum(axis=-1)) * mask


def ceiling_theta() -> np.ndarray:
    """The constant +3 coordinator as a member of the family."""
    theta = np.zeros(len(FEATURES))
    theta[-1] = CEILING_BIAS
    return theta


@dataclass(frozen=True)
class Setting:
    """What every batch runs: the coordinator kind searched, the env and its workload."""

    kind: str
    rows: int
    cols: int
    densities: tuple[float, ...]
    seeds: tuple[int, ...]
    steps: int
    overrides: dict[str, Any]
    edge_policy: Policy | None  # the frozen edge of a cloud search

    @property
    def metric(self) -> str:
        return headline_metric(self.overrides.get("model", "paper"))


def _edge_actions(setting: Setting, scheme: str, theta_env: np.ndarray | None,
                  k: int) -> Callable[[Any], np.ndarray | None]:
    """The edge actions [m/s^2] of a batch step: the searched family (edge search), the frozen
    edge policy, one call on the whole batch stacked (cloud search, schemes EE and EEC), or
    none (scheme E: the rules alone)."""
    if setting.kind == "edge" and theta_env is not None:
        return lambda st: linear_actions(st.edge_obs, st.edge_mask, theta_env)
    policy = setting.edge_policy
    if setting.kind == "cloud" and policy is not None and scheme != "E":
        def frozen(st: Any) -> np.ndarray:
            a = policy(st.edge_obs.reshape(-1, k, k, 3), st.edge_mask.reshape(-1, k))
            return np.asarray(a, np.float64).reshape(st.edge_mask.shape)
        return frozen
    return lambda st: None


def run_batch(setting: Setting, thetas: np.ndarray | None,
              progress: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Run each parameter vector (rows of ``thetas``) on every (density, seed) pair, all as one
    batch; ``None`` runs the baseline scheme instead (E for an edge search, EE with the frozen
    edge for a cloud search). Returns the metric [m/s] and the strict collision events, both
    (n_policies, n_densities, n_seeds)."""
    n_pol = 1 if thetas is None else len(thetas)
    pairs = [(d, s) for d in setting.densities for s in setting.seeds]
    b = n_pol * len(pairs)
    scheme = KIND_SCHEMES[setting.kind][1 if thetas is None else 0]
    env = BatchedMiVeCCEnv(
        batch_size=b, densities=[d for _ in range(n_pol) for d, _ in pairs],
        rows=setting.rows, cols=setting.cols, max_steps=setting.steps, scheme=scheme,
        observe={"edge"} if scheme != "EEC" else {"edge", "cloud"}, **setting.overrides)
    theta_env = None if thetas is None else np.repeat(thetas, len(pairs), axis=0)
    step = env.reset(seed=[s for _ in range(n_pol) for _, s in pairs])
    edge_fn = _edge_actions(setting, scheme, theta_env, env.k_edge)
    t0 = time.perf_counter()
    for i in range(setting.steps):
        cloud = None
        if setting.kind == "cloud" and theta_env is not None:
            cloud = linear_actions(step.cloud_obs, step.cloud_mask, theta_env)
        step = env.step(edge_fn(step), cloud)
        if progress and (i + 1) % 500 == 0:
            print(f"\r  {progress}: step {i + 1}/{setting.steps} ({b} environments, "
                  f"{time.perf_counter() - t0:.0f} s)", end="", file=sys.stderr, flush=True)
    if progress and setting.steps >= 500:
        print(file=sys.stderr)  # ends the progress line
    summary = env.summary()
    shape = (n_pol, len(setting.densities), len(setting.seeds))
    return (np.asarray(summary[setting.metric]).reshape(shape),
            np.asarray(summary["collisions"]).reshape(shape))


def ceiling_shares(v: np.ndarray, base: np.ndarray, ceiling: np.ndarray) -> np.ndarray:
    """Share of the ceiling's gain over the base realised by ``v`` [%], per policy and density
    (:func:`~mivecc_agents.train_eval.ceiling_share_pct` of the seeds' mean velocities); ``v``
    is (n_policies, n_densities, n_seeds), ``base`` and ``ceiling`` (1, n_densities, n_seeds).
    NaN where the ceiling gains nothing."""
    vm, bm, cm = v.mean(axis=2), base.mean(axis=2)[0], ceiling.mean(axis=2)[0]
    return np.array([[ceiling_share_pct(gain_pct(x, b), gain_pct(c, b))
                      for x, b, c in zip(row, bm, cm, strict=True)] for row in vm])


def cross_entropy_search(
    setting: Setting, population: int, elite: int, iterations: int, sigma0: float,
    rng: np.random.Generator,
) -> tuple[list[dict[str, Any]], np.ndarray, np.ndarray]:
    """The search. Each iteration evaluates the current mean and ``population - 1`` samples of
    N(mean, sigma^2) and refits mean and sigma to the ``elite`` best (sigma floored at
    ``SIGMA_FLOOR``). Returns one row per iteration, the final mean and the best parameter
    vector evaluated (by mean ceiling share)."""
    base, _ = run_batch(setting, None, "baseline")
    ceiling, _ = run_batch(setting, ceiling_theta()[None], "ceiling")
    if not (ceiling.mean(axis=2) > base.mean(axis=2)).any():
        raise cli_args.InputError(
            f"the constant +3 {setting.kind} gains nothing over the baseline at any of the "
            "search's densities: no share to search on (more --steps or higher --densities)")
    mean = np.zeros(len(FEATURES))
    mean[-1] = START_BIAS
    sigma = np.full(len(FEATURES), sigma0)
    history: list[dict[str, Any]] = []
    best_theta, best_score = mean.copy(), -math.inf
    for it in range(iterations):
        thetas = np.vstack([mean, mean + sigma * rng.standard_normal((population - 1,
                                                                      len(FEATURES)))])
        v, events = run_batch(setting, thetas, f"iteration {it + 1}/{iterations}")
        share = ceiling_shares(v, base, ceiling)  # (population, n_densities)
        score = np.nanmean(share, axis=1)
        order = np.argsort(-score, kind="stable")
        if score[order[0]] > best_score:
            best_score, best_theta = float(score[order[0]]), thetas[order[0]].copy()
        history.append({"iteration": it + 1, "mean_policy_share_pct": float(score[0]),
                        "best_share_pct": float(score[order[0]]),
                        "median_share_pct": float(np.median(score)),
                        "best_min_share_pct": float(np.nanmin(share[order[0]])),
                        "best_events": int(events[order[0]].sum()),
                        "sigma_mean": float(sigma.mean())})
        print(f"iteration {it + 1}: mean policy {score[0]:.1f} %, best {score[order[0]]:.1f} %"
              f" of the ceiling's gain (median {np.median(score):.1f} %)", file=sys.stderr)
        elites = thetas[order[:elite]]
        mean = elites.mean(axis=0)
        sigma = np.maximum(elites.std(axis=0), SIGMA_FLOOR)
    return history, mean, best_theta


def table_check(setting: Setting, thetas: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """Each named parameter vector and the ceiling on ``setting`` (the table's seeds): one row
    per density with each policy's share of the ceiling's gain [%] and strict events."""
    base, base_events = run_batch(setting, None, "table baseline")
    names = ["ceiling", *thetas]
    stacked = np.vstack([ceiling_theta(), *thetas.values()])
    v, events = run_batch(setting, stacked, "table policies")
    share = ceiling_shares(v, base, v[:1])
    rows = []
    for j, density in enumerate(setting.densities):
        row: dict[str, Any] = {"density": density, "base_mps": float(base[0, j].mean()),
                               "base_events": int(base_events[0, j].sum())}
        for i, name in enumerate(names):
            row[f"{name}_mps"] = float(v[i, j].mean())
            row[f"{name}_gain_pct"] = gain_pct(v[i, j].mean(), base[0, j].mean())
            row[f"{name}_events"] = int(events[i, j].sum())
            if name != "ceiling":
                row[f"{name}_share_pct"] = float(share[i, j])
        rows.append(row)
    return rows


def _plot(history: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    it = [h["iteration"] for h in history]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.plot(it, [h["mean_policy_share_pct"] for h in history], "o-", label="search mean")
    ax.plot(it, [h["best_share_pct"] for h in history], "s--", label="best of the iteration")
    ax.plot(it, [h["median_share_pct"] for h in history], ":", label="median of the iteration")
    ax.axhline(100.0, color="k", lw=1, label="constant +3 (ceiling)")
    ax.set_xlabel("iteration")
    ax.set_ylabel("share of the ceiling's gain [%]")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = cli_args.Parser(prog="benchmarks/headroom_search.py",
                             description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=("edge", "cloud"), required=True)
    parser.add_argument("--model", choices=("paper", "released"), default="released")
    parser.add_argument("--grid", type=cli_args.grid, default=(3, 3))
    parser.add_argument("--densities", type=cli_args.density, nargs="+",
                        default=[900.0, 1500.0, 2100.0], help="the search's densities")
    parser.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[1000],
                        help="the search's seeds (not the table's)")
    parser.add_argument("--steps", type=cli_args.count(1), default=1500)
    parser.add_argument("--population", type=cli_args.count(2), default=16)
    parser.add_argument("--elite", type=cli_args.count(1), default=4)
    parser.add_argument("--iterations", type=cli_args.count(1), default=10)
    parser.add_argument("--sigma", type=cli_args.number(0.0, low_ok=False), default=1.0,
                        help="initial standard deviation of every parameter")
    parser.add_argument("--search-seed", type=cli_args.seed, default=0,
                        help="seed of the search's own generator")
    parser.add_argument("--table-seeds", type=cli_args.seed, nargs="+", default=[0, 1, 2])
    parser.add_argument("--table-steps", type=cli_args.count(1), default=3000)
    parser.add_argument("--cloud-period", type=cli_args.count(1), default=10,
                        help="cloud search: steps between cloud decisions (the shipped "
                             "clouds': 10)")
    parser.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", default=[],
                        help="other config fields, e.g. safety_shield=true")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = parser.parse_args(argv)
    if args.elite > args.population:
        parser.error(f"--elite: must be in [1, --population] = [1, {args.population}], "
                     f"got {args.elite}")
    cli_args.check_distinct("--densities", args.densities)
    cli_args.check_distinct("--seeds", args.seeds)
    cli_args.check_distinct("--table-seeds", args.table_seeds)
    overrides = config_overrides(args.set_items, args.model, OWN_FIELDS)
    cli_args.writable_dir("--out", args.out)
    overrides["model"] = args.model
    if args.kind == "cloud":
        overrides["cloud_period"] = args.cloud_period
    shield = from_overrides(**overrides).safety_shield
    edge_policy = None
    if args.kind == "cloud":
        torch.set_num_threads(1)
        edge_policy = pretrained_policies(args.model, safety_shield=shield)["edge"]
    rows, cols = args.grid
    search = Setting(args.kind, rows, cols, tuple(args.densities), tuple(args.seeds),
                     args.steps, overrides, edge_policy)
    t0 = time.perf_counter()
    history, mean, best = cross_entropy_search(
        search, args.population, args.elite, args.iterations, args.sigma,
        np.random.default_rng(args.search_seed))
    search_s = time.perf_counter() - t0
    table = Setting(args.kind, rows, cols, tuple(DENSITIES), tuple(args.table_seeds),
                    args.table_steps, overrides, edge_policy)
    check = table_check(table, {"search_mean": mean, "search_best": best})
    wall = time.perf_counter() - t0

    stem = args.out / f"headroom_{args.kind}_{args.model}"
    with open(stem.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(history[0]))
        writer.writeheader()
        writer.writerows(history)
    grid = f"{rows}x{cols}"
    _plot(history, stem.with_suffix(".png"),
          f"{args.kind} search, {args.model} model, {grid}, densities "
          f"{'/'.join(f'{d:g}' for d in args.densities)} veh/lane/h, seeds "
          f"{' '.join(map(str, args.seeds))}")
    base = "MiVeCC-E" if args.kind == "edge" else "MiVeCC-EE (shipped edge)"
    command = "python benchmarks/headroom_search.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    lines = [
        f"Command: `{command}` ({wall:.0f} s; search {search_s:.0f} s)",
        "",
        f"Search: {grid}, {args.population} candidates x {args.iterations} iterations, "
        f"densities {', '.join(f'{d:g}' for d in args.densities)} veh/lane/h, seeds "
        f"{', '.join(map(str, args.seeds))}, {args.steps} steps; metric {search.metric}; "
        f"share of the constant +3 {args.kind}'s gain over {base} [%]:",
        "",
        "| iteration | search mean | best | median | best's weakest density | best's events |",
        "|---|---|---|---|---|---|",
        *(f"| {h['iteration']} | {h['mean_policy_share_pct']:.1f} | {h['best_share_pct']:.1f}"
          f" | {h['median_share_pct']:.1f} | {h['best_min_share_pct']:.1f} | "
          f"{h['best_events']} |" for h in history),
        "",
        "Parameters (" + ", ".join(FEATURES) + "):",
        "",
        f"- search mean: {np.array2string(mean, precision=3)}",
        f"- best evaluated: {np.array2string(best, precision=3)}",
        "",
        f"On the table's setting ({grid}, seeds {', '.join(map(str, args.table_seeds))}, "
        f"{args.table_steps} steps); gain over {base} [%], share of the ceiling's gain [%], "
        "strict events (base / ceiling / policy):",
        "",
        "| density | ceiling gain | search mean: gain, share | search best: gain, share | "
        "events |",
        "|---|---|---|---|---|",
        *(f"| {r['density']:g} | {r['ceiling_gain_pct']:+.2f} | "
          f"{r['search_mean_gain_pct']:+.2f}, {r['search_mean_share_pct']:.0f} | "
          f"{r['search_best_gain_pct']:+.2f}, {r['search_best_share_pct']:.0f} | "
          f"{r['base_events']} / {r['ceiling_events']} / {r['search_mean_events']}, "
          f"{r['search_best_events']} |" for r in check),
    ]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    result = {"command": command, "wall_s": wall, "search_s": search_s, "history": history,
              "mean": mean.tolist(), "best": best.tolist(), "table": check,
              "features": FEATURES}
    stem.with_suffix(".json").write_text(json.dumps(result, indent=1))
    print("\n".join(lines))
    print(f"wrote {stem}.md / .csv / .json / .png")
    return result


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
