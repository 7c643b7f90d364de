"""Periodic deterministic evaluation during training (eval_log.csv, eval_curve.png)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

pytest.importorskip("torchrl")

from mivecc_agents.checkpoints import load_checkpoint
from mivecc_agents.evaluation import evaluate_batch
from mivecc_agents.policies import load_policy
from mivecc_agents.presets import EVAL_SEED0, preset_with
from tests.agents.tiny import TINY, train_tiny_edge


def test_edge_training_logs_deterministic_evaluations(tmp_path):
    preset = preset_with(TINY, {"eval_every_frames": "100", "eval_steps": "400",
                                "eval_seeds": "2"})
    path = train_tiny_edge(tmp_path, preset=preset)
    with (tmp_path / "eval_log.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["frames"]) for r in rows] == [0, 100, 200]  # before, during, at the end
    assert (tmp_path / "eval_curve.png").stat().st_size > 10_000
    # the last row is the final policy's EE against E on the evaluation seeds
    seeds = [EVAL_SEED0, EVAL_SEED0 + 1]
    ee = evaluate_batch("EE", 1, 1, 1500, 400, seeds, policies={"edge": load_policy(path)},
                        progress=False)
    e = evaluate_batch("E", 1, 1, 1500, 400, seeds, progress=False)
    mean = lambda rs: sum(r["avg_travel_velocity_mps"] for r in rs) / len(rs)  # noqa: E731
    last = rows[-1]
    assert float(last["velocity_mps"]) == pytest.approx(mean(ee), rel=1e-12)
    assert float(last["baseline_mps"]) == pytest.approx(mean(e), rel=1e-12)
    assert float(last["gain_pct"]) == pytest.approx(100 * (mean(ee) / mean(e) - 1), rel=1e-9)
    assert {r["baseline_mps"] for r in rows} == {last["baseline_mps"]}
    # the constant +3 edge on the same seeds: the ceiling of every row
    from mivecc_agents.policies import constant_policy

    ceiling = evaluate_batch("EE", 1, 1, 1500, 400, seeds, progress=False,
                             policies={"edge": constant_policy("edge", 3.0, 15)})
    assert {r["ceiling_mps"] for r in rows} == {last["ceiling_mps"]}
    assert float(last["ceiling_mps"]) == pytest.approx(mean(ceiling), rel=1e-12)
    assert float(last["ceiling_gain_pct"]) == pytest.approx(
        100 * (mean(ceiling) / mean(e) - 1), rel=1e-9)
    for r in rows:  # the share of the ceiling's gain the policy realises
        assert float(r["ceiling_share_pct"]) == pytest.approx(
            100 * float(r["gain_pct"]) / float(r["ceiling_gain_pct"]), rel=1e-12)
    # edge_best.pt holds the policy of the best evaluation (mean gain over the densities)
    best_row = max(rows, key=lambda r: float(r["gain_pct"]))  # one density: the row's gain
    best = load_checkpoint(tmp_path / "edge_best.pt")
    assert best["frames"] == int(best_row["frames"])
    assert best["metrics"]["eval_gain_pct"] == pytest.approx(float(best_row["gain_pct"]))
    best_ee = evaluate_batch("EE", 1, 1, 1500, 400, seeds, progress=False,
                             policies={"edge": load_policy(tmp_path / "edge_best.pt")})
    assert mean(best_ee) == pytest.approx(float(best_row["velocity_mps"]), rel=1e-12)
    assert "optimizer" not in best and "loss" not in best  # slim, as the shipped exports
    # a resumed run starts from the recorded best, a fresh run from nothing
    from mivecc_agents.training import _best_score

    assert best["metrics"]["eval_select"] == "mean_gain"
    assert _best_score(tmp_path / "edge_best.pt", "mean_gain") == best["metrics"]["eval_gain_pct"]
    assert _best_score(tmp_path / "edge_best.pt", "min_ceiling_share") == float("-inf")
    assert _best_score(tmp_path / "absent.pt", "mean_gain") == float("-inf")


def test_evaluation_on_another_grid_keeps_the_policy_with_the_best_ceiling_share(tmp_path):
    """``eval_rows`` x ``eval_cols`` replace the training grid in the evaluation, and
    ``eval_select=min_ceiling_share`` keeps the policy whose weakest density realises the
    largest share of the constant +3 edge's gain."""
    preset = preset_with(TINY, {"eval_every_frames": "50", "eval_steps": "300",
                                "eval_rows": "1", "eval_cols": "2",
                                "eval_select": "min_ceiling_share"})
    train_tiny_edge(tmp_path, preset=preset)
    with (tmp_path / "eval_log.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["frames"]) for r in rows] == [0, 100, 200]  # iterations of 100 frames
    e = evaluate_batch("E", 1, 2, 1500, 300, [EVAL_SEED0], progress=False)[0]
    assert float(rows[0]["baseline_mps"]) == pytest.approx(e["avg_travel_velocity_mps"],
                                                           rel=1e-12)
    assert {r["grid"] for r in rows} == {"1x2"}
    shares = [float(r["ceiling_share_pct"]) for r in rows]
    best_row = rows[shares.index(max(shares))]
    best = load_checkpoint(tmp_path / "edge_best.pt")
    assert best["frames"] == int(best_row["frames"])
    assert best["metrics"]["eval_select"] == "min_ceiling_share"
    assert best["metrics"]["eval_score"] == pytest.approx(max(shares))
    from mivecc_agents.training import _best_score

    assert _best_score(tmp_path / "edge_best.pt", "min_ceiling_share") == pytest.approx(
        max(shares))


def test_the_rules_rank_evaluations_differently():
    from mivecc_agents.train_eval import EvalScores

    higher_mean, steadier = EvalScores(3.0, 80.0), EvalScores(2.5, 95.0)
    assert higher_mean.score("mean_gain") > steadier.score("mean_gain")
    assert steadier.score("min_ceiling_share") > higher_mean.score("min_ceiling_share")


def test_the_smallest_share_is_over_the_densities_whose_ceiling_gains():
    from mivecc_agents.train_eval import _over_numbers

    assert _over_numbers(np.min, [95.0, float("nan"), 101.0]) == 95.0
    assert np.isnan(_over_numbers(np.min, [float("nan")]))


@pytest.mark.parametrize(("field", "value"), [("eval_rows", "0"), ("eval_cols", "17"),
                                              ("eval_rows", "1.5"), ("eval_select", "best")])
def test_evaluation_grid_and_rule_are_checked(field, value):
    with pytest.raises(ValueError, match=field):
        preset_with("released", {field: value})


def test_a_resumed_log_of_an_older_version_keeps_its_columns(tmp_path):
    """A log written before the ceiling columns existed is continued with its own columns."""
    from mivecc_agents.networks import make_actor
    from mivecc_agents.train_eval import PeriodicEvaluation

    old = ("frames", "updates", "density", "velocity_mps", "baseline_mps", "gain_pct",
           "collisions", "baseline_collisions", "metric", "seeds", "steps")
    with (tmp_path / "eval_log.csv").open("w", newline="") as fh:
        csv.writer(fh).writerow(old)
    evaluation = PeriodicEvaluation("edge", 1, 1, [900], [EVAL_SEED0], 50, {}, tmp_path,
                                    append=True)
    evaluation(make_actor("edge", "edge").module, 10, 1)
    with (tmp_path / "eval_log.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == list(old) and len(rows) == 2 and len(rows[1]) == len(old)


def test_evaluating_does_not_change_what_is_learned(tmp_path):
    """The periodic evaluation (here on another grid) draws nothing from the training's
    generators: the final actor equals the one of a run without it, weight for weight."""
    import torch

    plain = train_tiny_edge(tmp_path / "plain")
    evaluated = train_tiny_edge(tmp_path / "evaluated", preset=preset_with(
        TINY, {"eval_every_frames": "100", "eval_steps": "100", "eval_rows": "2"}))
    a, b = (load_checkpoint(p)["actor"] for p in (plain, evaluated))
    assert a.keys() == b.keys()
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_the_periodic_evaluation_stacks_policy_calls_at_any_thread_count(tmp_path, monkeypatch):
    """Its batch is fixed by the preset: it stacks as when the shipped policies were picked
    (``stack_policies=True``), not by ``evaluate_batch``'s one-thread default."""
    from mivecc_agents import train_eval
    from mivecc_agents.networks import make_actor

    seen: list[object] = []
    real = train_eval.evaluate_batch

    def recorded(*args, **kwargs):
        seen.append(kwargs.get("stack_policies"))
        return real(*args, **kwargs)

    monkeypatch.setattr(train_eval, "evaluate_batch", recorded)
    evaluation = train_eval.PeriodicEvaluation("edge", 1, 1, [900], [EVAL_SEED0], 20, {},
                                               tmp_path)
    evaluation(make_actor("edge", "edge").module, 10, 1)
    assert seen == [True, True, True]  # baseline, ceiling, the actor
