"""Deterministic evaluation of the policy being trained, every N frames (the learning curve).

The chunk-end values of the training log run under the exploration policy (and, in the
released trainer's stage I, with the raw edge action on every other step), so they say little
about the policy itself. :class:`PeriodicEvaluation` runs the current actor without noise on
fixed seeds, beside the scheme without it, and logs the gain:

* stage I (edge): scheme ``EE`` with the actor vs ``E``;
* stage II (cloud): ``EEC`` with the actor and the frozen stage-I edge vs ``EE`` with that edge.

Each evaluation is one batch of ``len(densities) x len(seeds)`` environments
(:func:`~mivecc_agents.evaluation.evaluate_batch`) of ``steps`` steps on the training grid (or
the preset's ``eval_rows`` x ``eval_cols``), with
the user's env fields (``--set``) but none of the preset's training-only fields (its reward form
and training-time edge selection). The metric is the average travel velocity [m/s], or the
released-style velocity (455 m metric) under ``model="released"``. Rows go to
``eval_log.csv`` (one per density and evaluation) and the curve to ``eval_curve.png``.

Once per run the stage's constant-action ceiling is evaluated on the same seeds: the scheme
with the trained coordinator replaced by one that always outputs +3 m/s^2 (``EE+3`` /
``EEC+3`` of ``benchmarks/paper_table.py``; the cloud at the run's ``cloud_period``). Its
velocity and gain are in every row (``ceiling_mps``, ``ceiling_gain_pct``) and dashed in the
curve, so the curve shows how much of that gain the policy realises; ``ceiling_share_pct`` is
that share, ``100 x gain_pct / ceiling_gain_pct`` (NaN where the ceiling gains nothing).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from mivecc_agents.evaluation import Policy, evaluate_batch
from mivecc_agents.policies import actor_policy, ceiling_policy

#: The scheme each coordinator kind is judged in, and the baseline it is judged against:
#: the edge in MiVeCC-EE against MiVeCC-E, the cloud in MiVeCC-EEC against MiVeCC-EE.
KIND_SCHEMES: dict[str, tuple[str, str]] = {"edge": ("EE", "E"), "cloud": ("EEC", "EE")}

#: Columns of ``eval_log.csv``.
EVAL_FIELDS = ("frames", "updates", "density", "velocity_mps", "baseline_mps", "gain_pct",
               "collisions", "baseline_collisions", "metric", "seeds", "steps", "ceiling_mps",
               "ceiling_gain_pct", "ceiling_share_pct", "grid")


class EvalScores(NamedTuple):
    """What one evaluation scores, over its densities.

    Attributes:
        mean_gain_pct: Mean gain over the baseline [%].
        min_ceiling_share_pct: Smallest share of the ceiling's gain realised [%] (NaN where
            no density's ceiling gains anything).
    """

    mean_gain_pct: float
    min_ceiling_share_pct: float

    def score(self, select: str) -> float:
        """The number the preset's ``eval_select`` ranks evaluations by (higher is better) [%]:
        ``"mean_gain"`` or ``"min_ceiling_share"``."""
        return self.mean_gain_pct if select == "mean_gain" else self.min_ceiling_share_pct


class PeriodicEvaluation:
    """Evaluate an actor deterministically against its stage's baseline (module docstring).

    Args:
        stage: ``"edge"`` or ``"cloud"``.
        rows, cols: evaluation grid (the training grid unless the preset names another).
        densities: [veh/lane/h].
        seeds: evaluation seeds (each density runs every seed).
        steps: steps per evaluation episode.
        config_overrides: env fields of the evaluation (the user's ``--set``).
        out_dir: folder of ``eval_log.csv`` and ``eval_curve.png``.
        edge_policy: stage II: the frozen edge's numpy policy (used in both runs).
        append: continue an existing log (a resumed run).

    Its batch (the densities x seeds) is fixed by the preset, so its policy calls are stacked
    wherever :func:`~mivecc_agents.evaluation.stacking_is_exact` allows, at any thread count
    (``stack_policies=True``), as when the shipped policies were picked: the documented
    training runs' evaluation logs stay what they were.
    """

    def __init__(
        self,
        stage: str,
        rows: int,
        cols: int,
        densities: Sequence[float],
        seeds: Sequence[int],
        steps: int,
        config_overrides: dict[str, Any],
        out_dir: Path,
        edge_policy: Policy | None = None,
        append: bool = False,
    ) -> None:
        self.stage = stage
        self.kind = "edge" if stage == "edge" else "cloud"
        self.scheme, base_scheme = KIND_SCHEMES[self.kind]
        self.grid = f"{rows}x{cols}"
        self._args = dict(rows=rows, cols=cols, densities=list(densities), steps=int(steps),
                          seeds=list(seeds), stack_policies=True, progress=False, warn=False)
        self._overrides = {k: v for k, v in config_overrides.items() if k != "max_steps"}
        self.metric = headline_metric(self._overrides.get("model", "paper"))
        self._edge = edge_policy
        base_policies = {"edge": edge_policy} if edge_policy is not None else {}
        self.baseline = self._per_density(
            evaluate_batch(base_scheme, **self._args, policies=base_policies, **self._overrides)
        )
        self.ceiling = self._per_density(
            evaluate_batch(self.scheme, **self._args, policies=self._ceiling_policies(),
                           **self._overrides)
        )
        self.csv_path = Path(out_dir) / "eval_log.csv"
        self.png_path = Path(out_dir) / "eval_curve.png"
        self._fields: Sequence[str] = EVAL_FIELDS
        if append and self.csv_path.exists():  # a log of an older version keeps its columns
            with self.csv_path.open(newline="") as fh:
                self._fields = next(csv.reader(fh), None) or EVAL_FIELDS
        else:
            with self.csv_path.open("w", newline="") as fh:
                csv.DictWriter(fh, fieldnames=EVAL_FIELDS).writeheader()

    def _ceiling_policies(self) -> dict[str, Policy]:
        """The scheme's policies with the trained kind's replaced by the constant +3 one."""
        from mivecc_env.config import from_overrides

        policies = {self.kind: ceiling_policy(self.kind, from_overrides(**self._overrides))}
        if self._edge is not None:
            policies["edge"] = self._edge
        return policies

    def _per_density(self, results: list[dict[str, Any]]) -> dict[float, tuple[float, float]]:
        """density -> (mean metric over seeds, collision events summed over seeds)."""
        out: dict[float, tuple[float, float]] = {}
        for d in self._args["densities"]:
            mine = [r for r in results if r["density"] == float(d)]
            out[float(d)] = (float(np.mean([r[self.metric] for r in mine])),
                             float(sum(r["collisions"] for r in mine)))
        return out

    def __call__(self, actor_net: torch.nn.Module, frames: int, updates: int) -> EvalScores:
        """Evaluate the actor now, append its rows to the log, redraw the curve.

        Returns:
            The mean gain and the smallest ceiling share over the densities.
        """
        policies = {self.kind: actor_policy(actor_net, self.kind)}
        if self._edge is not None:
            policies["edge"] = self._edge
        now = self._per_density(
            evaluate_batch(self.scheme, **self._args, policies=policies, **self._overrides)
        )
        gains, shares = [], []
        with self.csv_path.open("a", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=self._fields, extrasaction="ignore")
            for d, (v, coll) in now.items():
                base, base_coll = self.baseline[d]
                gain, ceiling_gain = gain_pct(v, base), gain_pct(self.ceiling[d][0], base)
                share = ceiling_share_pct(gain, ceiling_gain)
                gains.append(gain)
                shares.append(share)
                writer.writerow({"frames": frames, "updates": updates, "density": d,
                                 "velocity_mps": v, "baseline_mps": base, "gain_pct": gain,
                                 "collisions": coll, "baseline_collisions": base_coll,
                                 "metric": self.metric, "seeds": len(self._args["seeds"]),
                                 "steps": self._args["steps"],
                                 "ceiling_mps": self.ceiling[d][0],
                                 "ceiling_gain_pct": ceiling_gain,
                                 "ceiling_share_pct": share, "grid": self.grid})
        plot_eval_curve(self.csv_path, self.png_path,
                        f"{self.scheme} vs {'E' if self.stage == 'edge' else 'EE'} on {self.grid}")
        return EvalScores(_over_numbers(np.mean, gains), _over_numbers(np.min, shares))


def _over_numbers(reduce: Any, values: list[float]) -> float:
    """``reduce`` (``np.mean``, ``np.min``) of the values that are not NaN; NaN if none is."""
    finite = [x for x in values if not np.isnan(x)]
    return float(reduce(finite)) if finite else float("nan")


def headline_metric(model: str) -> str:
    """The velocity a model's coordinators are judged by [m/s]: the released-style velocity
    (455 m metric) under ``model="released"``, else the average travel velocity."""
    return "released_velocity_mps" if model == "released" else "avg_travel_velocity_mps"


def gain_pct(velocity_mps: float, baseline_mps: float) -> float:
    """Relative gain of ``velocity_mps`` over ``baseline_mps`` [%] (NaN without a baseline)."""
    return 100.0 * (velocity_mps / baseline_mps - 1.0) if baseline_mps > 0 else float("nan")


def ceiling_share_pct(gain: float, ceiling_gain: float) -> float:
    """Share of the constant-action ceiling's gain that a policy's ``gain`` realises [%],
    ``100 x gain / ceiling_gain`` (both [%] over the same baseline; NaN where the ceiling gains
    nothing)."""
    return 100.0 * gain / ceiling_gain if ceiling_gain > 0 else float("nan")


def plot_eval_curve(csv_path: Path, png_path: Path, title: str) -> Path:
    """Gain over the baseline [%] vs training frames, one line per density, and dashed in
    the same colour the constant +3 ceiling's gain where the log has it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with Path(csv_path).open() as fh:
        rows = list(csv.DictReader(fh))
    fig, ax = plt.subplots(figsize=(7, 4))
    for d in sorted({float(r["density"]) for r in rows}):
        mine = [r for r in rows if float(r["density"]) == d]
        line, = ax.plot([int(r["frames"]) for r in mine], [float(r["gain_pct"]) for r in mine],
                        "o-", label=f"{d:g} veh/lane/h")
        if mine[-1].get("ceiling_gain_pct"):
            ax.axhline(float(mine[-1]["ceiling_gain_pct"]), color=line.get_color(), ls="--",
                       lw=1.0, label=f"{d:g}: constant +3 (ceiling)")
    ax.axhline(0.0, color="grey", lw=0.8)
    metric = rows[0]["metric"] if rows else "avg_travel_velocity_mps"
    if rows and "seeds" in rows[0]:  # on a second line, so that the title fits the figure
        title += f"\n({rows[0]['seeds']} seed(s) x {rows[0]['steps']} steps per density)"
    ax.set_xlabel("training frames [env steps]")
    ax.set_ylabel(f"gain in {metric} [%]")
    ax.set_title(f"deterministic evaluation: {title}", fontsize="medium")
    if rows:
        ax.legend(title="density", fontsize="small")
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return Path(png_path)
