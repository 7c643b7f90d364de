"""Batch evaluation (all seeds and densities as one batch) equals one run per seed."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")

from mivecc_agents.evaluation import evaluate_batch, evaluate_scheme
from mivecc_agents.policies import pretrained_path, pretrained_policies

#: Keys that depend on the wall clock or the batch, not on the trajectory.
TIMING = {"steps_per_s", "wall_s", "batch_size"}


def _same(batch: dict, single: dict) -> list[str]:
    """Keys whose values differ (NaN, "no data", equals NaN)."""
    def differ(a, b) -> bool:
        return not (a == b or (isinstance(a, float) and isinstance(b, float) and a != a
                               and b != b))

    return [k for k in single if k not in TIMING and differ(batch[k], single[k])]


@pytest.mark.parametrize("scheme, grid, steps", [
    ("E", 1, 400), ("fixed-time", 1, 400), ("max-pressure", 1, 300), ("reservation", 1, 300),
    ("EE", 1, 400), ("EEC", 1, 300),
])
def test_batch_equals_one_run_per_seed(scheme: str, grid: int, steps: int) -> None:
    policies = pretrained_policies()
    if scheme in ("EE", "EEC") and not policies:
        pytest.skip("no shipped policies")
    densities, seeds = [900.0, 2100.0], [0, 5]
    batch = evaluate_batch(scheme, grid, grid, densities, steps, seeds, policies=policies,
                           progress=False, warn=False)
    assert [(r["density"], r["seed"]) for r in batch] == [
        (d, s) for d in densities for s in seeds]
    assert all(r["batch_size"] == 4 for r in batch)
    assert any(r["throughput"] > 0 for r in batch)  # vehicles left: the metrics are real
    for r in batch:
        single = evaluate_scheme(scheme, grid, grid, r["density"], steps, r["seed"],
                                 policies=policies, progress=False, warn=False)
        assert _same(r, single) == [], (scheme, r["density"], r["seed"])


def test_cli_several_seeds_is_one_batch(capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from mivecc_agents.cli import main

    code = main(["evaluate", "--scheme", "E", "--rows", "1", "--cols", "1", "--density", "1500",
                 "--steps", "350", "--seeds", "0", "1", "--json", "--no-progress"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert [r["batch_size"] for r in doc["runs"]] == [2, 2]
    single = evaluate_scheme("E", 1, 1, 1500.0, 350, 1, progress=False)
    assert _same(doc["runs"][1], single) == []


def test_cli_workers_share_the_seeds_and_give_the_same_runs(
    capsys: pytest.CaptureFixture[str]
) -> None:
    """``--workers 2`` runs the seeds in two processes (shares of 2 and 1 seeds), with the
    shipped policy of the config's model and shield setting loaded there (the released
    model's shield edge), and gives every run as one process does."""
    import json

    from mivecc_agents.cli import main

    base = ["evaluate", "--scheme", "EE", "--rows", "1", "--cols", "1", "--density", "2100",
            "--steps", "400", "--seeds", "4", "0", "2", "--json", "--no-progress",
            "--set", "model=released", "safety_shield=true"]
    docs = []
    for workers in ("1", "2"):
        assert main([*base, "--workers", workers]) == 0
        docs.append(json.loads(capsys.readouterr().out))
    one, two = (doc["runs"] for doc in docs)
    assert [r["seed"] for r in two] == [4, 0, 2]
    assert [r["batch_size"] for r in two] == [2, 2, 1] and [r["batch_size"] for r in one] == [3] * 3
    assert {r["edge_checkpoint"] for r in one + two} == {
        str(pretrained_path("edge", "released", safety_shield=True))}
    assert any(r["throughput"] > 0 for r in two)
    for a, b in zip(one, two, strict=True):
        assert _same(b, a) == [], a["seed"]


def test_aggregate_of_runs_with_and_without_data() -> None:
    """Means and spreads over seeds; a key without data in one run has neither (NaN), and no
    numpy warning is raised."""
    import math
    import warnings

    from mivecc_agents.evaluation import aggregate

    runs = [{"seed": 0, "v": 12.0, "ttc": math.inf, "scheme": "EE", "tag": "a"},
            {"seed": 1, "v": 13.0, "ttc": 2.5, "scheme": "EE", "tag": "b"}]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stats = aggregate(runs)
    assert stats["mean"]["seed"] == [0, 1] and stats["mean"]["scheme"] == "EE"
    assert stats["mean"]["v"] == 12.5 and stats["std"]["v"] == 0.5
    assert math.isnan(stats["mean"]["ttc"]) and math.isnan(stats["std"]["ttc"])
    assert "tag" not in stats["mean"]


def test_cli_workers_must_be_at_least_one(capsys: pytest.CaptureFixture[str]) -> None:
    from mivecc_agents.cli import main

    assert main(["evaluate", "--seeds", "0", "1", "--workers", "0"]) == 2
    assert "--workers: must be an integer >= 1, got '0'" in capsys.readouterr().err


@pytest.mark.parametrize("flag", [[], ["--stack-policies"]])
def test_cli_stacks_policy_calls_only_when_asked(flag: list[str], monkeypatch) -> None:
    from mivecc_agents import cli

    seen: list[bool] = []
    real = cli.evaluate_batch

    def recorded(*args, **kwargs):
        seen.append(kwargs["stack_policies"])
        return real(*args, **kwargs)

    monkeypatch.setattr(cli, "evaluate_batch", recorded)
    code = cli.main(["evaluate", "--scheme", "EE", "--rows", "3", "--cols", "3", "--steps", "20",
                     "--seeds", "0", "1", "--json", "--no-progress", *flag])
    assert code == 0 and seen == [bool(flag)]


def test_rules_study_batch_equals_single_runs() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import rules_study

    from mivecc_env.config import MiVeCCConfig
    from mivecc_env.metrics import episode_summary
    from mivecc_env.sim.core import Simulator

    runs = rules_study.run_batch(1, 1, [900.0, 1800.0], [0, 2], 300, end_rule="literal")
    pairs = [(900.0, 0), (900.0, 2), (1800.0, 0), (1800.0, 2)]
    for run, (d, s) in zip(runs, pairs, strict=True):
        sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=d, scheme="E",
                                     end_rule="literal"), seed=s)
        for _ in range(300):
            sim.step()
        assert run == episode_summary(sim)  # the unbatched simulator, seeded s
    assert runs[0] != runs[1]  # different seeds, different traffic


def test_on_step_sees_every_step_with_its_actions() -> None:
    seen: list[tuple[bool, tuple[int, ...], float]] = []

    def record(before, edge, cloud, after) -> None:
        seen.append((edge is None, cloud.shape, float(after.cloud_reward.sum())))

    from mivecc_agents.policies import constant_policy

    evaluate_batch("EEC", 1, 1, [900.0], 50, [0, 1], progress=False, warn=False,
                   policies={"cloud": constant_policy("cloud", 1.0, 1),
                             "edge": constant_policy("edge", 0.0, 1)},
                   on_step=record)
    assert len(seen) == 50
    assert all(not no_edge and shape[0] == 2 for no_edge, shape, _ in seen)
    e_steps: list[bool] = []
    evaluate_batch("E", 1, 1, 900.0, 20, [0], progress=False, warn=False,
                   on_step=lambda b, e, c, a: e_steps.append(e is None and c is None))
    assert e_steps == [True] * 20


def test_cli_runs_a_learned_cloud_at_its_training_period(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    from mivecc_agents.checkpoints import load_checkpoint, save_checkpoint
    from mivecc_agents.cli import main
    from mivecc_agents.policies import pretrained_path

    data = load_checkpoint(pretrained_path("cloud", "released"))
    data["config"] = {**data["config"], "cloud_period": 10}
    path = save_checkpoint(tmp_path / "cloud_p10.pt", data)
    base = ["evaluate", "--scheme", "EEC", "--rows", "1", "--cols", "1", "--steps", "40",
            "--json", "--no-progress", "--cloud-checkpoint", str(path), "--set", "model=released"]
    assert main(base) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["cloud_period"] == 10 and "cloud_period" not in out.err
    # an explicit period wins, with the mismatch warned about
    assert main([*base, "cloud_period=1"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["cloud_period"] == 1
    assert "trained deciding every 10 steps" in out.err
    # the period only matters to the cloud: EE runs as asked, a given cloud is ignored with a
    # warning, the shipped one is not even loaded (no warning)
    assert main([*base[:2], "EE", *base[3:]]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["cloud_period"] == 1
    assert out.err.count("warning") == 1 and "the policy is ignored" in out.err
    assert main([*base[:2], "EE", *base[3:11], "--set", "model=released"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["cloud_period"] == 1 and "warning" not in out.err


def test_evaluation_functions_adopt_a_learned_clouds_period() -> None:
    policies = pretrained_policies("released")
    period = policies["cloud"].config["cloud_period"]
    assert period > 1  # the shipped clouds decide every 10 steps
    batch = evaluate_batch("EEC", 1, 1, 1500, 30, [0], policies=policies, progress=False,
                           model="released")
    single = evaluate_scheme("EEC", 1, 1, 1500, 30, 0, policies=policies, progress=False,
                             model="released")
    assert batch[0]["cloud_period"] == single["cloud_period"] == period
    # an explicit period wins; schemes without the cloud keep the default
    explicit = evaluate_batch("EEC", 1, 1, 1500, 30, [0], policies=policies, progress=False,
                              model="released", cloud_period=1)
    ee = evaluate_scheme("EE", 1, 1, 1500, 30, 0, policies=policies, progress=False,
                         model="released")
    assert explicit[0]["cloud_period"] == ee["cloud_period"] == 1


def test_a_learned_cloud_is_asked_only_on_its_decision_steps() -> None:
    # Between decisions the env ignores the cloud action (tests/env/test_cloud_period.py), so
    # both evaluation paths call the cloud policy on the decision steps only: 0, 10, 20, 30, 40.
    # (with stack_policies=True evaluate_batch's check, before step 0, would count as step 0.)
    shipped = pretrained_policies("released")
    calls: list[int] = []  # the step of each call
    decided: list[int] = []  # environments whose cloud row is an action (not NaN), per step

    def cloud(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        calls.append(len(decided))
        return shipped["cloud"](obs, mask)

    cloud.config = shipped["cloud"].config  # type: ignore[attr-defined]  # period 10
    policies = {"edge": shipped["edge"], "cloud": cloud}

    def record(before, edge, cloud_action, after) -> None:
        decided.append(int((~np.isnan(cloud_action[:, 0])).sum()))

    batch = evaluate_batch("EEC", 1, 1, 1500, 45, [0, 1], policies=policies, progress=False,
                           model="released", on_step=record)
    assert sorted(set(calls)) == [0, 10, 20, 30, 40]
    assert decided == ([2] + [0] * 9) * 4 + [2] + [0] * 4
    calls.clear()
    single = evaluate_scheme("EEC", 1, 1, 1500, 45, 1, policies=policies, progress=False,
                             model="released")
    assert len(calls) == 5
    assert _same(batch[1], single) == []


def test_a_policy_is_called_once_per_step_when_stacking_is_exact() -> None:
    # With stack_policies=True, where stacking gives the per-environment bits (checked first),
    # the policy is called once per step for the whole batch; a policy whose output depends on
    # its batch size is called per environment, and the results still equal one run per seed.
    from mivecc_agents.evaluation import stacking_is_exact

    edge = pretrained_policies("released")["edge"]
    sizes: list[int] = []

    def counted(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        sizes.append(obs.shape[0])
        return edge(obs, mask)

    stacked = stacking_is_exact(edge, 2, 9, 15)  # 3x3: 9 edge nodes per environment
    batch = evaluate_batch("EE", 3, 3, [900.0, 2100.0], 150, [0], policies={"edge": counted},
                           progress=False, stack_policies=True)
    assert sizes[:3] == [18, 9, 9]  # the check: stacked, then one call per environment
    assert sizes[3:] == ([18] * 150 if stacked else [9] * 300)
    for r in batch:
        single = evaluate_scheme("EE", 3, 3, r["density"], 150, 0, policies={"edge": edge},
                                 progress=False)
        assert _same(r, single) == []

    def batch_dependent(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        return edge(obs, mask) + np.float32(1e-3 * obs.shape[0]) * mask

    assert not stacking_is_exact(batch_dependent, 2, 1, 15)

    def one_environment_only(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        if obs.shape[0] != 1:
            raise ValueError("written for one edge node")
        return edge(obs, mask)

    assert not stacking_is_exact(one_environment_only, 2, 1, 15)  # not stacked, no error
    policies = {"edge": batch_dependent}
    batch = evaluate_batch("EE", 1, 1, 1500, 200, [0, 3], policies=policies, progress=False)
    for r in batch:
        single = evaluate_scheme("EE", 1, 1, 1500, 200, r["seed"], policies=policies,
                                 progress=False)
        assert _same(r, single) == []


@pytest.mark.parametrize("stack_policies", [False, "default"])
def test_per_environment_calls_make_every_action_independent_of_the_batch(
    stack_policies: bool | str,
) -> None:
    # The stacking check samples random graphs; on real graphs, with two torch threads, the
    # shipped released shield edge (which passes it) rounded one action one ulp differently at
    # step 77 of (2100 veh/lane/h, seed 2) in this batch on the machine of session 33. By
    # default (and with stack_policies=False) every call has one environment's shapes: each
    # environment's actions at every step are its single run's, bit for bit.
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(2)  # the conftest's one thread hides the stacked rounding here
    try:
        _assert_per_environment_calls_match_single_run(
            {} if stack_policies == "default" else {"stack_policies": stack_policies})
    finally:
        torch.set_num_threads(threads)


def _assert_per_environment_calls_match_single_run(stacking: dict[str, bool]) -> None:
    edge = pretrained_policies("released", safety_shield=True)["edge"]
    sizes: list[int] = []

    def recorded(store: list[np.ndarray], env: int | None):
        def on_step(before, edge_actions, cloud, after) -> None:
            store.append(edge_actions[env if env is not None else 0].copy())
        return on_step

    def counted(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        sizes.append(obs.shape[0])
        return edge(obs, mask)

    in_batch: list[np.ndarray] = []
    alone: list[np.ndarray] = []
    common = dict(progress=False, model="released", safety_shield=True)
    batch = evaluate_batch("EE", 3, 3, [300.0, 2100.0], 100, [0, 1, 2],
                           policies={"edge": counted}, on_step=recorded(in_batch, 5),
                           **stacking, **common)
    assert set(sizes) == {9}  # one call per environment and step, no stacking check
    single = evaluate_batch("EE", 3, 3, [2100.0], 100, [2], policies={"edge": edge},
                            on_step=recorded(alone, None), **common)
    assert (batch[5]["density"], batch[5]["seed"]) == (2100.0, 2)
    assert len(in_batch) == len(alone) == 100
    assert all(a.tobytes() == b.tobytes() for a, b in zip(in_batch, alone, strict=True))
    assert _same(batch[5], single[0]) == []


@pytest.mark.parametrize("cloud", ["constant", "shipped"])
def test_per_lane_cloud_batch_equals_one_run_per_seed(cloud: str) -> None:
    """The paper's per-lane cloud graphs (``cloud_graphs="per_lane"``): one policy call on every
    lane graph of the batch gives each environment's single run."""
    from mivecc_agents.policies import constant_policy

    policies = pretrained_policies("released")
    if cloud == "constant":
        policies["cloud"] = constant_policy("cloud", 3.0, 60)
    elif "cloud" not in policies:
        pytest.skip("no shipped released cloud")
    kw = {"model": "released", "cloud_graphs": "per_lane"}
    batch = evaluate_batch("EEC", 2, 2, [900.0, 2100.0], 400, [1], policies=policies,
                           progress=False, warn=False, **kw)
    assert any(r["throughput"] > 0 for r in batch)
    for r in batch:
        single = evaluate_scheme("EEC", 2, 2, r["density"], 400, r["seed"], policies=policies,
                                 progress=False, warn=False, **kw)
        assert _same(r, single) == [], (cloud, r["density"])


def test_batch_actions_calls_clips_and_leaves_other_environments_at_zero() -> None:
    from mivecc_agents.evaluation import batch_actions

    calls: list[tuple[int, ...]] = []

    def policy(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        calls.append(obs.shape)
        return np.full(mask.shape, 5.0) * np.arange(1, mask.shape[-1] + 1)[None] / 10

    obs = np.zeros((3, 2, 4, 4, 3), np.float32)  # 3 environments, 2 graphs, K = 4
    mask = np.ones((3, 2, 4), np.float32)
    per_env = batch_actions(policy, obs, mask, 1.5, stacked=False)
    assert calls == [(2, 4, 4, 3)] * 3  # one call per environment, B = 1 shapes
    assert per_env.dtype == np.float64
    np.testing.assert_array_equal(per_env[0, 0], [0.5, 1.0, 1.5, 1.5])  # clipped to +-1.5
    calls.clear()
    stacked = batch_actions(policy, obs, mask, 1.5, stacked=True)
    assert calls == [(6, 4, 4, 3)]  # one call on the stacked graphs
    np.testing.assert_array_equal(stacked, per_env)
    calls.clear()
    some = batch_actions(policy, obs, mask, 1.5, stacked=True, envs=[2])
    assert calls == [(2, 4, 4, 3)]  # not the whole batch: per environment
    assert not some[:2].any() and some[2].any()
    assert not batch_actions(None, obs, mask, 1.5, stacked=True).any()  # no policy: zeros
    with pytest.raises(ValueError, match="policy returned shape"):
        batch_actions(lambda o, m: np.zeros(3), obs, mask, 1.5, stacked=False)
    with pytest.raises(ValueError, match=r"policy returned shape \(3,\), expected \(6, 4\)"):
        batch_actions(lambda o, m: np.zeros(3), obs, mask, 1.5, stacked=True)


def test_evaluation_names_its_bad_arguments() -> None:
    from mivecc_env import ConfigError

    with pytest.raises(ConfigError, match=r"^densities and seeds: need at least one each"):
        evaluate_batch("E", 1, 1, [900.0], 5, [])
    with pytest.raises(ConfigError, match=r"^seed: must be an integer >= 0, got -1$"):
        evaluate_batch("E", 1, 1, [900.0], 5, [0, -1])
    with pytest.raises(ConfigError, match=r"^seed: must be an integer >= 0, got 1.5$"):
        evaluate_scheme("E", 1, 1, 900.0, 5, 1.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^policy returned shape \(2,\), expected \(1, 15\)$"):
        evaluate_scheme("EE", 1, 1, 900.0, 5, 0, policies={"edge": lambda o, m: np.zeros(2)})
    with pytest.raises(ConfigError, match=r"^densities: must be numbers \[veh/lane/h\], "
                       r"got \['a'\]$"):
        evaluate_batch("E", 1, 1, ["a"], 5, [0])  # type: ignore[list-item]
    with pytest.raises(ConfigError, match=r"^policies: 'edge' must be a callable \(obs, mask\) "
                       r"-> actions or None, got int$"):
        evaluate_scheme("EE", 1, 1, 900.0, 5, 0, policies={"edge": 3})  # type: ignore[dict-item]


def test_stacking_check_names_an_empty_shape() -> None:
    from mivecc_agents.evaluation import stacking_is_exact

    def policy(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        return np.asarray(mask, np.float32)

    assert stacking_is_exact(policy, 3, 2, 4)
    for args, name in (((0, 2, 4), "n_envs"), ((3, 0, 4), "n_agents"), ((3, 2, 0), "k")):
        with pytest.raises(ValueError, match=rf"^{name}: must be an integer >= 1, got 0$"):
            stacking_is_exact(policy, *args)
