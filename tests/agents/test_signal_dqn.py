"""PA-DQN (``mivecc_agents.signal_dqn``): settings, training, checkpoints, held decisions,
the ``pa-dqn`` scheme and its command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from mivecc_agents import cli
from mivecc_agents.checkpoints import CheckpointError
from mivecc_agents.evaluation import evaluate_batch, evaluate_scheme
from mivecc_agents.policies import load_policy, pretrained_path
from mivecc_agents.signal_dqn import (
    HeldPhases,
    KeptNetwork,
    SignalDQNPolicy,
    greedy_throughput,
    kept_episodes,
    kept_note,
    shipped_policy_path,
    train_signal_dqn,
    training_env,
)
from mivecc_agents.signal_dqn_settings import SignalDQNSettings
from mivecc_env.config import ConfigError
from tests.agents.tiny import keep_best_and_last, retrain_is_identical

TINY = SignalDQNSettings(episodes=2, batch=2, episode_steps=300, warmup=8, densities=(900.0,))


@pytest.fixture(scope="module")
def tiny_run():
    return train_signal_dqn(TINY)


@pytest.mark.parametrize(("field", "value", "message"), [
    ("gamma", 2.0, r"gamma: must be a number in \[0.0, 1.0\], got 2.0"),
    ("episodes", 0, r"episodes: must be an integer in \[1, 100000\], got 0"),
    ("lr", float("nan"), r"lr: must be a number in \(0.0, 1.0\]"),
    ("densities", (), r"densities: must be one or more numbers"),
    ("decision_period_s", 0.25, r"decision_period_s: must be a whole number >= 1 of steps"),
    ("episode_steps", 50, r"episode_steps: must hold at least one decision \(100 steps\)"),
    ("config", {"rows": 2}, r"config: rows is set by the training settings"),
    ("config", {"omega": 7.0}, r"omega"),
    ("batch", True, r"batch: must be an integer"),
    ("keep_network", "first", r"keep_network: must be one of best, last, got 'first'"),
])
def test_settings_name_the_bad_field(field: str, value, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        SignalDQNSettings(**{field: value}).check()


def test_training_is_deterministic_and_leaves_torch_rng_alone(tiny_run) -> None:
    policy, log = tiny_run
    assert [r["episode"] for r in log] == [1, 2]
    assert np.isnan(log[0]["loss"]) and np.isfinite(log[1]["loss"])  # updates after warm-up
    log2 = retrain_is_identical(train_signal_dqn, TINY, policy, "net")
    assert [r["loss"] for r in log] == [r["loss"] for r in log2]
    other, _ = train_signal_dqn(SignalDQNSettings(**{**TINY.to_dict(), "seed": 1,
                                                     "densities": TINY.densities}))
    assert not torch.equal(other.net.net[0].weight, policy.net.net[0].weight)


def test_checkpoint_round_trip_and_bad_files(tiny_run, tmp_path) -> None:
    policy, _ = tiny_run
    path = policy.save(tmp_path / "p.pt")
    loaded = SignalDQNPolicy.load(path)
    obs = np.random.default_rng(0).uniform(0, 20, (64, 15)).astype(np.float32)
    np.testing.assert_array_equal(policy(obs), loaded(obs))
    assert loaded.decision_period_s == 10.0 and loaded.checkpoint == str(path)
    with pytest.raises(ValueError, match=r"obs: expected shape \(n, 15\)"):
        loaded(obs[:, :14])
    broken = tmp_path / "broken.pt"
    broken.write_bytes(path.read_bytes()[:200])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        SignalDQNPolicy.load(broken)
    with pytest.raises(CheckpointError, match="holds the 'edge' policy"):
        SignalDQNPolicy.load(pretrained_path("edge"))
    with pytest.raises(CheckpointError, match="holds the 'signal_dqn' policy"):
        load_policy(path, expected_kind="edge")


class _Counting:
    """A signal policy that wants phase 1 everywhere and counts its calls."""

    decision_period_s = 2.0

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self.calls += 1
        return np.ones(obs.shape[0], dtype=np.int64)


def test_held_phases_decide_on_the_period_only() -> None:
    policy = _Counting()
    held = HeldPhases(policy, period_steps=20)
    obs = np.zeros((3, 4, 15), np.float32)
    decided = []
    for t in range(45):
        if held.due(t):
            decided.append(t)
            held.decide(obs)
        out = held.phases
        assert out.shape == (3, 4) and (out == 1).all()
    assert policy.calls == 3 * 3  # t = 0, 20, 40, once per environment
    assert decided == [0, 20, 40]


def test_scheme_follows_the_policy_and_needs_one() -> None:
    phases = []
    evaluate_scheme("pa-dqn", 1, 1, 600, 400, 0, policies={"signal": _Counting()},
                    progress=False,
                    step_hook=lambda env, t: phases.append(
                        int(env.batched.sim.signal_phases.phase[0, 0])))
    assert phases[-1] == 1 and all(p == 1 for p in phases[-200:])
    with pytest.raises(ConfigError, match=r"scheme 'pa-dqn' needs policies\['signal'\]"):
        evaluate_scheme("pa-dqn", 1, 1, 600, 10, 0, progress=False)
    with pytest.raises(ConfigError, match=r"'signal' is used by scheme"):
        evaluate_scheme("max-pressure", 1, 1, 600, 10, 0, policies={"signal": _Counting()},
                        progress=False)


def test_shipped_policy_batch_equals_single_runs_and_repeats() -> None:
    assert shipped_policy_path(1, 1).name == "signal_dqn_1x1.pt"
    assert shipped_policy_path(2, 3) == shipped_policy_path(3, 3)
    for rows, cols in ((1, 1), (3, 3)):
        shipped = SignalDQNPolicy.load(shipped_policy_path(rows, cols))
        assert shipped.decision_period_s == 10.0
        # made by the documented commands: the default settings on that grid
        # (trained before keep_network existed: the last network)
        assert shipped.settings == SignalDQNSettings(rows=rows, cols=cols,
                                                     keep_network="last").to_dict()
    policy = SignalDQNPolicy.load(shipped_policy_path(2, 2))
    batch = evaluate_batch("pa-dqn", 2, 2, [900, 1800], 600, [0, 1],
                           policies={"signal": policy}, progress=False)
    single = evaluate_scheme("pa-dqn", 2, 2, 1800, 600, 1, policies={"signal": policy},
                             progress=False)
    again = evaluate_scheme("pa-dqn", 2, 2, 1800, 600, 1, policies={"signal": policy},
                            progress=False)
    keys = ("avg_travel_velocity_mps", "throughput", "backlog", "collisions", "min_pet_s")
    assert [single[k] for k in keys] == [batch[3][k] for k in keys] == [again[k] for k in keys]
    assert single["coordinator_actions"] == "policy" and single["control"] == "signalized"


def test_command_line(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert cli.main(["train-signal", "--out", str(out), "--episodes", "1", "--batch", "1",
                     "--episode-steps", "200", "--warmup", "1", "--densities", "900",
                     "--save-validated"]) == 0
    assert capsys.readouterr().out.strip() == str(out / "signal_dqn.pt")
    # the only validated network (after the last episode) is the one kept
    validated = SignalDQNPolicy.load(out / "validated" / "episode_01.pt")
    kept = SignalDQNPolicy.load(out / "signal_dqn.pt")
    for a, b in zip(validated.net.parameters(), kept.net.parameters(), strict=True):
        assert torch.equal(a, b)
    assert (out / "train_log.csv").read_text().startswith("episode,epsilon,")
    assert (out / "learning_curve.png").stat().st_size > 10_000
    assert cli.main(["evaluate", "--scheme", "pa-dqn", "--signal-checkpoint",
                     str(out / "signal_dqn.pt"), "--rows", "1", "--cols", "1", "--steps", "200",
                     "--json", "--no-progress"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["scheme"] == "pa-dqn" and result["signal_checkpoint"].endswith("signal_dqn.pt")
    for argv, message in (
        (["train-signal", "--out", str(out), "--tau", "0"], "tau: must be a number in (0.0"),
        (["train-signal", "--out", str(out), "--keep-network", "last", "--save-validated"],
         "--save-validated: needs --keep-network best"),
        (["evaluate", "--scheme", "pa-dqn", "--no-pretrained"], "give --signal-checkpoint"),
        (["evaluate", "--scheme", "pa-dqn", "--signal-checkpoint", str(tmp_path / "none.pt")],
         "--signal-checkpoint: "),
    ):
        assert cli.main(argv) == 2
        assert message in capsys.readouterr().err


@pytest.mark.parametrize("grid", [1, 3])
def test_shipped_policy_moves_more_traffic_than_the_classical_signals(grid: int) -> None:
    """What the shipped policies were trained for (docs/comparators.md, PA-DQN): at high
    demand more vehicles leave the network than under fixed-time or max-pressure (seed 0, 1800
    veh/lane/h, 300 s: 312 / 297 / 251 on 1x1, 669 / 656 / 616 on 3x3)."""
    policy = SignalDQNPolicy.load(shipped_policy_path(grid, grid))
    kw = {"rows": grid, "cols": grid, "density": 1800, "steps": 3000, "seed": 0,
          "progress": False}
    learned = evaluate_scheme("pa-dqn", policies={"signal": policy}, **kw)
    for scheme in ("fixed-time", "max-pressure"):
        assert learned["throughput"] > evaluate_scheme(scheme, **kw)["throughput"], scheme
    assert learned["collisions"] == 0


def test_kept_network_restores_the_best_scored_state_the_earlier_of_ties() -> None:
    net = torch.nn.Linear(2, 1)
    scores = iter([1.0, 3.0, 3.0, 2.0])
    keeper = KeptNetwork(net, lambda: next(scores))
    states = []
    for value in range(4):
        net.weight.data.fill_(float(value))
        states.append(keeper.consider())
    assert states == [1.0, 3.0, 3.0, 2.0]
    keeper.restore()
    assert torch.equal(net.weight, torch.full((1, 2), 1.0))  # the state scored first at 3
    KeptNetwork(net, lambda: 0.0).restore()  # nothing considered: nothing changes
    assert torch.equal(net.weight, torch.full((1, 2), 1.0))


def test_keep_best_trains_as_keep_last_and_returns_the_best_validated_network() -> None:
    # no exploration decay: every episode is validated, and the first k episodes of a longer
    # run are the whole of a k-episode run
    base = {**TINY.to_dict(), "episodes": 3, "eps_start": 0.3, "eps_end": 0.3,
            "densities": (900.0, 1800.0)}
    best, log, _, last_log, copies = keep_best_and_last(train_signal_dqn, SignalDQNSettings,
                                                        base, "net")
    assert "validation_throughput" not in last_log[0]
    for row, same in zip(log, last_log, strict=True):
        assert {k: v for k, v in row.items() if k not in ("wall_s", "validation_throughput")} \
            == {k: v for k, v in same.items() if k != "wall_s"}
    validated = [r["validation_throughput"] for r in log]
    assert all(np.isfinite(validated)) and best.settings["keep_network"] == "best"
    [(stage, episode, value, latest)] = kept_episodes(log)
    assert (stage, value, latest) == (1, max(validated), validated[-1])
    assert episode == 1 + validated.index(max(validated))
    prefix, _ = train_signal_dqn(SignalDQNSettings(**{**base, "episodes": episode,
                                                      "keep_network": "last"}))
    for a, b, c in zip(best.net.parameters(), prefix.net.parameters(),
                       copies[episode - 1][1].net.parameters(), strict=True):
        assert torch.equal(a, b) and torch.equal(a, c)
    cfg = SignalDQNSettings(**base).env_config()
    env = training_env(SignalDQNSettings(**base), cfg, batch=2)
    again = greedy_throughput(SignalDQNSettings(**base), env,
                              lambda obs: best(obs.reshape(-1, 15)).reshape(obs.shape[:2]))
    assert again == value  # the kept network's validation run, repeated
    # the network is asked one environment at a time, as in an evaluation (HeldPhases)
    shapes: list[tuple[int, ...]] = []

    def spy(obs: np.ndarray) -> np.ndarray:
        shapes.append(obs.shape)
        return best(obs.reshape(-1, 15)).reshape(obs.shape[:2])

    assert greedy_throughput(SignalDQNSettings(**base), env, spy) == value
    assert shapes and set(shapes) == {(1, 1, 15)} and len(shapes) % 2 == 0
    assert kept_note(log).startswith(f"kept the network of the best greedy validation run "
                                     f"after episode {episode}: {value:.1f} vehicles out")
    assert kept_note(last_log) is None


def test_validation_counts_once_the_exploration_has_decayed_and_at_the_end() -> None:
    _, log = train_signal_dqn(SignalDQNSettings(**{
        **TINY.to_dict(), "episodes": 4, "eps_decay_fraction": 0.5, "keep_network": "best",
        "densities": TINY.densities}))
    # 3 decisions per episode, decay over 6: the last decision of episode 3 explores at eps_end
    assert [np.isfinite(r["validation_throughput"]) for r in log] == [False, False, True, True]
    _, log = train_signal_dqn(SignalDQNSettings(**{
        **TINY.to_dict(), "episodes": 2, "eps_decay_fraction": 1.0, "keep_network": "best",
        "densities": TINY.densities}))
    assert [np.isfinite(r["validation_throughput"]) for r in log] == [False, True]  # the last


def test_checkpoints_from_before_keep_network_kept_the_last_network() -> None:
    for rows, cols in ((1, 1), (3, 3)):
        shipped = SignalDQNPolicy.load(shipped_policy_path(rows, cols))
        assert shipped.settings["keep_network"] == "last"
