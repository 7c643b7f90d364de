"""Coder (``mivecc_agents.coder``): regions, the global Q, settings, two-stage training,
checkpoints, the ``coder`` scheme and its command line."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from mivecc_agents import cli
from mivecc_agents.checkpoints import CheckpointError
from mivecc_agents.coder import (
    REGION_ACTIONS,
    CoderPolicy,
    CoderSettings,
    GlobalQ,
    coordinate_ascent,
    grid_regions,
    joint_index,
    joint_phases,
    shipped_policy_path,
    train_coder,
)
from mivecc_agents.evaluation import evaluate_batch, evaluate_scheme
from mivecc_agents.policies import pretrained_path
from mivecc_agents.signal_dqn import SignalDQNPolicy, SignalQNetwork
from mivecc_agents.signal_dqn import shipped_policy_path as shipped_pa_dqn_path
from mivecc_agents.signal_policy_files import load_signal_policy, shipped_signal_policy_path
from mivecc_env.config import ConfigError
from tests.agents.tiny import retrain_is_identical

TINY = CoderSettings(episodes=2, global_episodes=2, batch=2, episode_steps=300, warmup=8,
                     rows=2, cols=2, densities=(900.0,))


@pytest.fixture(scope="module")
def tiny_run():
    return train_coder(TINY)


def test_regions_are_the_2x2_blocks_of_the_grid() -> None:
    np.testing.assert_array_equal(grid_regions(3, 3), [[0, 1, 3, 4], [1, 2, 4, 5],
                                                       [3, 4, 6, 7], [4, 5, 7, 8]])
    np.testing.assert_array_equal(grid_regions(2, 3), [[0, 1, 3, 4], [1, 2, 4, 5]])
    assert grid_regions(4, 4).shape == (9, 4)  # larger grids: coordinate ascent
    for rows, cols in ((1, 1), (1, 4), (4, 1)):
        with pytest.raises(ConfigError, match=rf"rows, cols: Coder needs a grid of at least "
                                              rf"2x2, got {rows}x{cols}"):
            grid_regions(rows, cols)


def test_joint_phases_and_their_index() -> None:
    table = joint_phases(5)
    assert table.shape == (32, 5) and set(np.unique(table)) == {0, 1}
    assert len({tuple(r) for r in table}) == 32
    np.testing.assert_array_equal(joint_index(table), np.arange(32))
    np.testing.assert_array_equal(table[6], [0, 1, 1, 0, 0])


def _regional(seed: int) -> SignalQNetwork:
    torch.manual_seed(seed)
    return SignalQNetwork(torch.full((60,), 20.0), 16, REGION_ACTIONS)


@pytest.mark.parametrize("aggregated", [False, True])
def test_global_q_is_the_weighted_sum_of_regional_values(aggregated: bool, tiny_run) -> None:
    regional = _regional(0)
    aggregation = tiny_run[0].aggregation if aggregated else None
    q = GlobalQ(regional, aggregation, 2, 3)
    obs = torch.from_numpy(np.random.default_rng(1).uniform(0, 20, (3, 6, 15)).astype(
        np.float32))
    values = q(obs.reshape(3, -1))
    assert values.shape == (3, 64)
    regions = grid_regions(2, 3)
    with torch.no_grad():
        for b, a in itertools.product(range(3), (0, 5, 37, 63)):
            phases = joint_phases(6)[a]
            expected = 0.0
            for ids in regions:
                region_obs = obs[b, ids].reshape(-1)
                weight = 1.0
                if aggregated:
                    grid_mean = obs[b].mean(0)
                    weight = float(aggregation(torch.cat([region_obs, grid_mean])))
                expected += weight * float(regional(region_obs)[joint_index(phases[ids])])
            assert float(values[b, a]) == pytest.approx(expected, rel=1e-5, abs=1e-5)


def test_policy_takes_the_best_joint_phase(tiny_run) -> None:
    policy = tiny_run[0]
    obs = np.random.default_rng(2).uniform(0, 20, (4, 15)).astype(np.float32)
    q = GlobalQ(policy.regional, policy.aggregation, 2, 2)
    with torch.no_grad():
        best = int(q(torch.from_numpy(obs.reshape(-1))).argmax())
    np.testing.assert_array_equal(policy(obs), joint_phases(4)[best])
    on_3x3 = policy.for_grid(3, 3)
    assert (on_3x3.rows, on_3x3.cols) == (3, 3) and policy.for_grid(2, 2) is policy
    assert on_3x3(np.zeros((9, 15), np.float32)).shape == (9,)
    with pytest.raises(ValueError, match=r"obs: expected shape \(9, 15\) for the 3x3 grid"):
        on_3x3(obs)
    with pytest.raises(ConfigError, match="Coder needs a grid"):
        policy.for_grid(1, 1)
    on_4x4 = policy.for_grid(4, 4)
    assert not on_4x4.exhaustive and on_4x4(np.zeros((16, 15), np.float32)).shape == (16,)


def test_coordinate_ascent_reaches_a_local_optimum_of_the_global_q() -> None:
    """On larger grids the decision is a joint phase no single flip improves; on 3x3, where
    the exhaustive optimum is known, it is never above it and mostly equal."""
    policy = CoderPolicy.load(shipped_policy_path())
    rng = np.random.default_rng(4)
    regions = grid_regions(3, 3)
    equal = 0
    for _ in range(40):
        obs = torch.from_numpy(rng.uniform(0, 15, (9 * 15,)).astype(np.float32))
        q = GlobalQ(policy.regional, policy.aggregation, 3, 3)
        with torch.no_grad():
            values = q(obs).numpy()
            q_region, weights = (x.numpy() for x in q.region_values(obs))
        phases = coordinate_ascent(q_region, weights[:, 0], regions, 9)
        found = values[joint_index(phases)]
        for i in range(9):  # no single flip improves
            flipped = phases.copy()
            flipped[i] ^= 1
            assert values[joint_index(flipped)] <= found
        assert found <= values.max()
        equal += bool(found == values.max())
    assert equal >= 30


@pytest.mark.parametrize(("field", "value", "message"), [
    ("rows", 1, r"rows, cols: Coder needs a grid of at least 2x2 .* got 1x3"),
    ("cols", 5, r"rows, cols: Coder needs .* at most 12 intersections, got 3x5"),  # training
    ("global_episodes", 0, r"global_episodes: must be an integer in \[1, 100000\], got 0"),
    ("global_hidden", 1.5, r"global_hidden: must be an integer"),
    ("global_eps_start", float("nan"), r"global_eps_start: must be a number in \[0.0, 1.0\]"),
    ("gamma", 2.0, r"gamma: must be a number in \[0.0, 1.0\], got 2.0"),
])
def test_settings_name_the_bad_field(field: str, value, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        CoderSettings(**{field: value}).check()


def test_training_is_deterministic_and_the_second_stage_keeps_the_regions(tiny_run) -> None:
    policy, log = tiny_run
    assert [(r["episode"], r["stage"]) for r in log] == [(1, 1), (2, 1), (3, 2), (4, 2)]
    assert log[2]["wall_s"] > log[1]["wall_s"]  # counts on over both stages
    # each stage fills its own buffer (8 transitions of warm-up: 2 per decision, 3 decisions
    # per episode), then updates
    assert [bool(np.isfinite(r["loss"])) for r in log] == [False, True, False, True]
    log2 = retrain_is_identical(train_coder, TINY, policy, "regional")
    assert [r["loss"] for r in log] == [r["loss"] for r in log2]
    # the aggregation stage trains the aggregation network only
    shorter, _ = train_coder(CoderSettings(**{**TINY.to_dict(), "global_episodes": 1,
                                              "densities": TINY.densities}))
    for a, b in zip(policy.regional.state_dict().values(),
                    shorter.regional.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    assert not torch.equal(policy.aggregation.net[0].weight, shorter.aggregation.net[0].weight)
    assert all(p.requires_grad for p in policy.regional.parameters())


def test_checkpoint_round_trip_and_bad_files(tiny_run, tmp_path) -> None:
    policy, _ = tiny_run
    path = policy.save(tmp_path / "coder.pt")
    loaded = CoderPolicy.load(path)
    assert load_signal_policy(path).scheme == "coder"
    rng = np.random.default_rng(3)
    for _ in range(20):
        obs = rng.uniform(0, 20, (4, 15)).astype(np.float32)
        np.testing.assert_array_equal(policy(obs), loaded(obs))
    assert (loaded.rows, loaded.cols, loaded.decision_period_s) == (2, 2, 10.0)
    broken = tmp_path / "broken.pt"
    broken.write_bytes(path.read_bytes()[:300])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        CoderPolicy.load(broken)
    with pytest.raises(CheckpointError, match="holds the 'signal_dqn' policy"):
        CoderPolicy.load(shipped_pa_dqn_path(3, 3))
    with pytest.raises(CheckpointError, match="holds the 'coder' policy"):
        SignalDQNPolicy.load(path)
    with pytest.raises(CheckpointError, match=r"holds the 'edge' policy, but a signal policy "
                                              r"\('signal_dqn' or 'coder'\)"):
        load_signal_policy(pretrained_path("edge"))


def test_scheme_needs_a_coder_policy_on_a_grid(tiny_run) -> None:
    policy, _ = tiny_run
    with pytest.raises(ConfigError, match=r"scheme 'coder' needs policies\['signal'\]"):
        evaluate_scheme("coder", 2, 2, 600, 10, 0, progress=False)
    with pytest.raises(ConfigError, match="'signal' is a policy of scheme 'pa-dqn', not of "
                                          "'coder'"):
        evaluate_scheme("coder", 2, 2, 600, 10, 0, progress=False,
                        policies={"signal": SignalDQNPolicy.load(shipped_pa_dqn_path(3, 3))})
    with pytest.raises(ConfigError, match="'signal' is a policy of scheme 'coder'"):
        evaluate_scheme("pa-dqn", 2, 2, 600, 10, 0, progress=False, policies={"signal": policy})
    with pytest.raises(ConfigError, match="Coder needs a grid of at least 2x2"):
        evaluate_batch("coder", 1, 1, [600], 10, [0], progress=False,
                       policies={"signal": policy})


def test_scheme_sets_the_policy_to_its_grid_and_decides_on_the_period(tiny_run) -> None:
    """Evaluation binds the policy to the grid (``for_grid``) and asks it every 10 s; batch
    runs equal single runs."""
    policy = tiny_run[0]
    calls, grids = [], []

    class Recording:
        scheme, decision_period_s = "coder", policy.decision_period_s

        def for_grid(self, rows: int, cols: int) -> Recording:
            grids.append((rows, cols))
            return self

        def __call__(self, obs: np.ndarray) -> np.ndarray:
            calls.append(obs.shape)
            return np.ones(obs.shape[0], dtype=np.int64)

    phases = []
    evaluate_scheme("coder", 2, 3, 1500, 350, 0, policies={"signal": Recording()},
                    progress=False, step_hook=lambda env, t: phases.append(
                        env.batched.sim.signal_phases.phase[0].copy()))
    assert grids == [(2, 3)] and calls == [(6, 15)] * 4  # t = 0, 100, 200, 300
    assert (phases[-1] == 1).all()
    batch = evaluate_batch("coder", 2, 2, [900, 1500], 350, [0, 1],
                           policies={"signal": policy}, progress=False)
    single = evaluate_scheme("coder", 2, 2, 1500, 350, 1, policies={"signal": policy},
                             progress=False)
    keys = ("avg_travel_velocity_mps", "throughput", "backlog", "collisions", "min_pet_s")
    assert [single[k] for k in keys] == [batch[3][k] for k in keys]
    assert single["control"] == "signalized" and single["coordinator_actions"] == "policy"


def test_command_line(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert cli.main(["train-coder", "--out", str(out), "--episodes", "1", "--global-episodes",
                     "1", "--batch", "1", "--episode-steps", "200", "--warmup", "1",
                     "--densities", "900", "--rows", "2", "--cols", "2"]) == 0
    captured = capsys.readouterr()
    assert captured.out.strip() == str(out / "coder.pt")
    assert "episode 2/2 (stage 2)" in captured.err and "mivecc: kept the network" in captured.err
    assert (out / "train_log.csv").read_text().startswith("episode,epsilon,")
    assert (out / "learning_curve.png").stat().st_size > 10_000
    assert cli.main(["evaluate", "--scheme", "coder", "--signal-checkpoint",
                     str(out / "coder.pt"), "--rows", "2", "--cols", "3", "--steps", "200",
                     "--json", "--no-progress"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["scheme"] == "coder" and result["signal_checkpoint"].endswith("coder.pt")
    for argv, message in (
        (["train-coder", "--out", str(out), "--rows", "1"], "rows, cols: Coder needs a grid"),
        (["evaluate", "--scheme", "coder", "--no-pretrained"],
         "scheme coder needs a signal policy; give --signal-checkpoint"),
        (["evaluate", "--scheme", "coder", "--rows", "3", "--cols", "3", "--signal-checkpoint",
          str(shipped_pa_dqn_path(3, 3))], "holds a pa-dqn policy; scheme coder needs a coder"),
        (["evaluate", "--scheme", "pa-dqn", "--signal-checkpoint", str(out / "coder.pt")],
         "holds a coder policy; scheme pa-dqn needs a pa-dqn"),
        (["evaluate", "--scheme", "coder", "--rows", "1", "--cols", "1", "--signal-checkpoint",
          str(out / "coder.pt")], "rows, cols: Coder needs a grid of at least 2x2"),
    ):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1


def test_shipped_policy_is_the_documented_run() -> None:
    assert shipped_signal_policy_path("coder", 3, 3) == shipped_policy_path()
    assert shipped_signal_policy_path("pa-dqn", 1, 1) == shipped_pa_dqn_path(1, 1)
    shipped = CoderPolicy.load(shipped_policy_path())
    assert (shipped.rows, shipped.cols) == (3, 3)
    # its documented command; trained before keep_network existed: the last network
    assert shipped.settings == CoderSettings(keep_network="last").to_dict()


def test_shipped_policy_keeps_its_documented_place_among_the_signals() -> None:
    """docs/comparators.md, Coder: at high demand faster than every classical signal controller
    and moving more vehicles than max-pressure, fewer than fixed-time (3x3, seed 0, 1800
    veh/lane/h, 300 s: 5.61 / 4.68 / 5.25 m/s and 646 / 656 / 616 vehicles out for Coder /
    fixed-time / max-pressure)."""
    policy = CoderPolicy.load(shipped_policy_path())
    kw = {"rows": 3, "cols": 3, "density": 1800, "steps": 3000, "seed": 0, "progress": False}
    coder = evaluate_scheme("coder", policies={"signal": policy}, **kw)
    fixed, pressure = (evaluate_scheme(s, **kw) for s in ("fixed-time", "max-pressure"))
    assert coder["avg_travel_velocity_mps"] > max(fixed["avg_travel_velocity_mps"],
                                                  pressure["avg_travel_velocity_mps"])
    assert pressure["throughput"] < coder["throughput"] < fixed["throughput"]
    assert coder["collisions"] == 0


def test_evaluate_notes_signal_collisions_without_keep_clear(capsys) -> None:
    # Coder's training seed 1 blocks boxes: 8 strict events at 1200 veh/lane/h, seed 0
    # (docs/comparators.md, "Training seeds of the learned signal comparators"), none with the rule
    path = (Path(__file__).resolve().parents[2] / "docs" / "results" / "coder" /
            "training_seeds" / "seed1" / "coder.pt")
    argv = ["evaluate", "--scheme", "coder", "--signal-checkpoint", str(path), "--density",
            "1200", "--seed", "0", "--json", "--no-progress"]
    assert cli.main([*argv, "--set", "signal_keep_clear=false"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["collisions"] == 8
    assert captured.err.strip() == (
        "mivecc: note: 8 strict collision events under signals without the keep-clear rule; "
        "vehicles that drive into a blocked box collide there: rerun with the rule (the "
        "default, signal_keep_clear=true) to tell them apart (docs/comparators.md, \"Keeping "
        "the box clear\")")
    assert cli.main(argv) == 0  # the rule is on by default
    captured = capsys.readouterr()
    assert json.loads(captured.out)["collisions"] == 0 and captured.err == ""


def test_a_training_that_ends_worse_than_its_regional_stage_is_named() -> None:
    # the committed training logs: the shipped policy's, seeds 1 and 2, the Xeon retrainings
    # with and without the keep-clear rule; only the last one ended with worse networks
    # (docs/comparators.md,
    # "Signal policies trained with the keep-clear rule, and on another CPU")
    import csv

    from mivecc_agents.coder import training_shortfall

    results = Path(__file__).resolve().parents[2] / "docs" / "results" / "coder"

    def note(folder: str) -> str | None:
        with open(results / folder / "train_log.csv", newline="", encoding="utf-8") as fh:
            return training_shortfall(list(csv.DictReader(fh)))

    for folder in ("train_3x3", "training_seeds/seed1", "training_seeds/seed2",
                   "trained_with_keep_clear/with_rule"):
        assert note(folder) is None, folder
    assert note("trained_with_keep_clear/without_rule").startswith(
        "warning: the aggregation stage's last 5 episodes moved 385 vehicles per training "
        "environment, 78 % of the regional stage's 493: the networks the training ended with "
        "do worse than its regional stage did")
    assert training_shortfall([{"stage": 1, "throughput": 400.0}]) is None  # one stage only


def test_command_line_warns_of_a_training_shortfall(tmp_path, capsys, monkeypatch) -> None:
    from mivecc_agents import coder

    trained = coder.train_coder

    def collapsed(settings, on_episode=None):
        policy, log = trained(settings, on_episode)
        return policy, [{**row, "throughput": 100.0 * (3 - row["stage"])} for row in log]

    monkeypatch.setattr(coder, "train_coder", collapsed)
    assert cli.main(["train-coder", "--out", str(tmp_path), "--episodes", "1",
                     "--global-episodes", "1", "--batch", "1", "--episode-steps", "200",
                     "--warmup", "1", "--densities", "900", "--rows", "2", "--cols", "2"]) == 0
    err = capsys.readouterr().err
    assert ("mivecc: warning: the aggregation stage's last 1 episodes moved 100 vehicles per "
            "training environment, 50 % of the regional stage's 200") in err


def test_a_policy_without_its_aggregation_sums_the_regional_values() -> None:
    from mivecc_env import signal_agents

    shipped = CoderPolicy.load(shipped_policy_path())
    plain = shipped.without_aggregation()
    assert plain.aggregation is None and plain.regional is shipped.regional
    obs = np.zeros((9, signal_agents.OBS_DIM), np.float32)
    assert plain(obs).shape == (9,)
    assert plain.for_grid(4, 4).aggregation is None
    with pytest.raises(ValueError, match="without its aggregation network is not saved"):
        plain.save("never.pt")


@pytest.mark.slow
def test_the_xeon_retrained_regional_network_is_the_poor_one() -> None:
    # vehicles out (means over seeds 0-2) at 300, 1200, 2100 veh/lane/h, with and without each
    # policy's aggregation (docs/comparators.md,
    # "Signal policies trained with the keep-clear rule, and on another CPU")
    folder = Path(__file__).resolve().parents[2] / "docs" / "results" / "coder"
    expected = {folder / "trained_with_keep_clear" / "without_rule" / "coder.pt":
                ([166, 428, 427], [162, 427, 438]),
                shipped_policy_path(): ([218, 570, 645], [217, 570, 645])}
    for path, (with_it, without_it) in expected.items():
        policy = CoderPolicy.load(path)
        for p, out in ((policy, with_it), (policy.without_aggregation(), without_it)):
            runs = evaluate_batch("coder", 3, 3, [300.0, 1200.0, 2100.0], 3000, [0, 1, 2],
                                  policies={"signal": p}, progress=False)
            assert [round(np.mean([r["throughput"] for r in runs if r["density"] == d]))
                    for d in (300.0, 1200.0, 2100.0)] == out, path


def test_keep_best_keeps_the_best_validated_network_of_each_stage(tmp_path, capsys) -> None:
    from mivecc_agents.signal_dqn import kept_episodes

    # no exploration decay: every episode validated, and a shorter regional stage is the
    # longer one's beginning
    base = {**TINY.to_dict(), "episodes": 3, "global_episodes": 2, "eps_start": 0.2,
            "eps_end": 0.2, "global_eps_start": 0.2, "densities": (900.0, 2100.0)}
    best, log = train_coder(CoderSettings(**base))  # keep_network="best", the default
    _, last_log = train_coder(CoderSettings(**{**base, "keep_network": "last"}))
    for row, same in zip(log, last_log, strict=True):  # the same until the regional stage ends
        if row["stage"] == 1:
            np.testing.assert_equal([row["throughput"], row["loss"]],
                                    [same["throughput"], same["loss"]])
    kept = kept_episodes(log)
    assert [k[0] for k in kept] == [1, 2] and all(np.isfinite(r["validation_throughput"])
                                                  for r in log)
    for stage, episode, value, _ in kept:
        values = [r["validation_throughput"] for r in log if r["stage"] == stage]
        first = min(r["episode"] for r in log if r["stage"] == stage)
        assert value == max(values) and episode == first + values.index(value)
    # the kept regional network is the one a regional stage of that many episodes ends with
    prefix, _ = train_coder(CoderSettings(**{**base, "episodes": kept[0][1],
                                              "keep_network": "last"}))
    for a, b in zip(best.regional.parameters(), prefix.regional.parameters(), strict=True):
        assert torch.equal(a, b)
    out = tmp_path / "best"
    assert cli.main(["train-coder", "--out", str(out), "--episodes", "1", "--global-episodes",
                     "1", "--batch", "1", "--episode-steps", "200", "--warmup", "1",
                     "--densities", "900", "--rows", "2", "--cols", "2"]) == 0
    err = capsys.readouterr().err
    assert "validation " in err and ("mivecc: kept the network of the best greedy validation "
                                     "run after episode 1 (stage 1): ") in err
    assert "; after episode 2 (stage 2): " in err
    assert "validation_throughput" in (out / "train_log.csv").read_text().splitlines()[0]
    assert CoderPolicy.load(out / "coder.pt").settings["keep_network"] == "best"
    assert cli.main(["train-coder", "--out", str(out), "--keep-network", "first"]) == 2
    assert "--keep-network: invalid choice: 'first'" in capsys.readouterr().err
