"""CoMADDPG (``mivecc_agents.comaddpg``): transitions and rewards, the critic's inputs, settings,
deterministic training, checkpoints, the ``comaddpg`` scheme and its command line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from mivecc_agents import cli
from mivecc_agents.checkpoints import CheckpointError
from mivecc_agents.comaddpg import (
    SHIPPED_PATH,
    VALIDATION_COLUMNS,
    CoMADDPGPolicy,
    CoMADDPGSettings,
    VehicleActor,
    VehicleLearner,
    greedy_validation,
    kept_note,
    kept_row,
    neighbour_actions,
    neighbour_observations,
    train_comaddpg,
    transitions,
    validation_env,
    validation_key,
    validation_runs,
)
from mivecc_agents.comaddpg_settings import vehicle_agent_fields
from mivecc_agents.evaluation import evaluate_batch, evaluate_scheme
from mivecc_agents.signal_dqn import shipped_policy_path as shipped_pa_dqn_path
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.config import ConfigError
from mivecc_env.vehicle_agents import observe_vehicles, vehicle_commands
from tests.agents.tiny import keep_best_and_last, retrain_is_identical

TINY = CoMADDPGSettings(episodes=2, batch=2, episode_steps=150, warmup=64, minibatch=32,
                        densities=(1500.0,), validation_steps=150, validation_envs=1)


@pytest.fixture(scope="module")
def tiny_run():
    return train_comaddpg(TINY)


def _filled_env(density: float = 2100.0) -> BatchedMiVeCCEnv:
    env = BatchedMiVeCCEnv(batch_size=1, rows=1, cols=1, density=density,
                           **vehicle_agent_fields())
    env.reset(seed=5)
    for _ in range(300):
        env.step_commands(None, None)
    return env


def test_transitions_follow_each_vehicle_and_end_where_it_leaves() -> None:
    env = _filled_env()
    cfg, settings = env.config, CoMADDPGSettings()
    agents = observe_vehicles(env.sim, settings.k)
    action = np.linspace(-3.0, 3.0, len(agents))
    env.step_vehicles(vehicle_commands(agents, action, 1))
    nxt = observe_vehicles(env.sim, settings.k)
    target = np.full(len(nxt), 1.5)
    batch = transitions(agents, action, nxt, target, env.sim.last_events, cfg, settings)
    next_of = {int(v): i for i, v in enumerate(nxt.vid)}
    for i, vid in enumerate(agents.vid):
        j = next_of.get(int(vid))
        assert batch.terminated[i] == (j is None)
        v_new = np.clip(agents.velocity[i] + action[i] * cfg.dt_s, cfg.velocity_floor_mps,
                        cfg.v_max_mps)
        expected = (v_new - cfg.v_max_mps) / (cfg.v_max_mps - cfg.velocity_floor_mps)
        if j is None:
            np.testing.assert_array_equal(batch.next_obs[i], 0.0)
        else:
            expected += settings.safety_weight * min(nxt.sv[j], 0.0) / 20.0
            np.testing.assert_array_equal(batch.next_obs[i], nxt.obs[j])
            real = nxt.ref_agent[j] >= 0
            np.testing.assert_array_equal(batch.next_neighbour_action[i], np.where(real, 1.5, 0))
            np.testing.assert_array_equal(batch.next_neighbour_mask[i], real)
        assert batch.reward[i, 0] == pytest.approx(expected, abs=1e-6)
    assert batch.terminated.sum() < len(agents) / 5
    nb, mask = neighbour_actions(agents, action)
    real = agents.ref_agent >= 0
    np.testing.assert_array_equal(nb, np.where(real, action[agents.ref_agent], 0.0).astype(
        np.float32))
    np.testing.assert_array_equal(mask, real)


def test_a_collided_vehicle_loses_the_penalty_and_its_transition_ends() -> None:
    env = _filled_env()
    settings = CoMADDPGSettings()
    hit = None
    for _ in range(400):  # full throttle everywhere: the crossing streams collide
        agents = observe_vehicles(env.sim, settings.k)
        action = np.full(len(agents), 3.0)
        env.step_vehicles(vehicle_commands(agents, action, 1))
        events = env.sim.last_events
        if events.collided_slot.size:
            hit = np.isin(agents.slot, events.collided_slot)
            break
    assert hit is not None and hit.sum() >= 2
    nxt = observe_vehicles(env.sim, settings.k)
    batch = transitions(agents, action, nxt, np.zeros(len(nxt)), events, env.config, settings)
    assert np.all(batch.terminated[hit])
    assert np.all(batch.reward[hit, 0] <= -settings.collision_penalty)
    assert np.all(batch.reward[~hit, 0] > -settings.collision_penalty)


def test_the_critic_reads_the_reference_vehicles_actions() -> None:
    torch.manual_seed(0)
    learner = VehicleLearner(CoMADDPGSettings(), 3.0)
    obs = torch.rand(5, 8, 3) * 2 - 1
    action = torch.zeros(5, 1)
    mask = torch.ones(5, 7)
    q0 = learner.critic(obs, action, torch.zeros(5, 7), mask)
    q1 = learner.critic(obs, action, torch.full((5, 7), 3.0), mask)
    assert not torch.allclose(q0, q1)
    mu, mu_target = learner.act(obs.numpy())
    np.testing.assert_array_equal(mu, mu_target)  # the target starts as a copy
    assert np.all(np.abs(mu) <= 3.0)


def test_the_observations_critic_reads_the_references_observations() -> None:
    env = _filled_env()
    settings = CoMADDPGSettings(critic_view="observations")
    agents = observe_vehicles(env.sim, settings.k)
    nb_obs = neighbour_observations(agents)
    assert nb_obs.shape == (len(agents), settings.k - 1, settings.k, 3)
    has = agents.ref_agent >= 0
    assert has.any() and (~has).any()
    np.testing.assert_array_equal(nb_obs[has], agents.obs[agents.ref_agent[has]])
    assert not nb_obs[~has].any()
    # the transitions carry them, now and (for vehicles that go on) at the next state
    action = np.zeros(len(agents))
    env.step_vehicles(vehicle_commands(agents, action, 1))
    nxt = observe_vehicles(env.sim, settings.k)
    batch = transitions(agents, action, nxt, np.zeros(len(nxt)), env.sim.last_events,
                        env.config, settings)
    np.testing.assert_array_equal(batch.neighbour_obs, nb_obs)
    assert batch.next_neighbour_obs.shape == nb_obs.shape
    assert not batch.next_neighbour_obs[batch.terminated].any()
    assert transitions(agents, action, nxt, np.zeros(len(nxt)), env.sim.last_events,
                       env.config, CoMADDPGSettings()).neighbour_obs is None
    torch.manual_seed(0)
    learner = VehicleLearner(settings, 3.0)
    obs = torch.from_numpy(agents.obs[:5])
    args = (obs, torch.zeros(5, 1), torch.zeros(5, 7), torch.ones(5, 7))
    q0 = learner.critic(*args, torch.zeros(5, 7, 8, 3))
    q1 = learner.critic(*args, torch.from_numpy(nb_obs[:5]))
    assert not torch.allclose(q0, q1)


def test_settings_errors_name_the_field() -> None:
    for kw, message in (({"k": 1}, r"k: must be an integer in \[2, 64\]"),
                        ({"gamma": 1.5}, r"gamma: must be a number in \[0.0, 1.0\]"),
                        ({"noise_hold_steps": 0}, "noise_hold_steps: must be an integer"),
                        ({"critic_view": "all"},
                         "critic_view: must be one of actions, observations, got 'all'"),
                        ({"keep_network": "first"},
                         "keep_network: must be one of best, last, got 'first'"),
                        ({"densities": ()}, "densities: must be one or more numbers"),
                        ({"config": {"scheme": "E"}}, "config: scheme is set by the training"),
                        ({"config": {"model": "released"}}, "config: model is set by the"),
                        ({"config": {"omega": 7}}, "omega")):
        with pytest.raises(ConfigError, match=message):
            CoMADDPGSettings(**kw).check()


def test_training_is_deterministic_and_leaves_torch_rng_alone(tiny_run) -> None:
    policy, log = tiny_run
    assert [r["episode"] for r in log] == [1, 2]
    assert all(np.isfinite(r["critic_loss"]) for r in log)
    log2 = retrain_is_identical(train_comaddpg, TINY, policy, "actor")
    assert [r["reward_per_transition"] for r in log] == [r["reward_per_transition"]
                                                          for r in log2]


def test_training_with_the_observations_critic_is_deterministic() -> None:
    settings = CoMADDPGSettings(episodes=1, batch=2, episode_steps=150, warmup=64,
                                minibatch=32, densities=(1500.0,), critic_view="observations")
    first, log = train_comaddpg(settings)
    assert np.isfinite(log[0]["critic_loss"])
    retrain_is_identical(train_comaddpg, settings, first, "actor")
    assert first.settings["critic_view"] == "observations"


def test_validation_ranks_fewer_collisions_first_then_the_velocity() -> None:
    def run(collisions: float, velocity: float) -> dict[str, float]:
        return {"validation_collisions": collisions, "validation_reward": -0.1,
                "validation_velocity": velocity}

    ranked = sorted([run(2, 12.9), run(0, 12.7), run(0, 12.8), run(1, math.nan), run(1, 12.5)],
                    key=validation_key, reverse=True)
    # a run in which no vehicle finished (NaN velocity) ranks last among runs with as many
    # collisions
    assert [r["validation_collisions"] for r in ranked] == [0, 0, 1, 1, 2]
    assert [r["validation_velocity"] for r in ranked[:3]] == [12.8, 12.7, 12.5]
    assert math.isnan(ranked[3]["validation_velocity"]) and ranked[4]["validation_velocity"] == 12.9


def test_keep_best_trains_as_keep_last_and_returns_the_best_validated_actor() -> None:
    # no noise decay: every episode is validated, and the first k episodes of a longer run are
    # the whole of a k-episode run
    # (on the single intersection, long enough for vehicles to exit: a validation velocity)
    base = {**TINY.to_dict(), "episodes": 3, "noise_start": 0.5, "noise_end": 0.5,
            "densities": (900.0, 2100.0), "rows": 1, "cols": 1, "episode_steps": 300,
            "validation_steps": 400, "validation_envs": 2}
    best, log, _, last_log, _ = keep_best_and_last(train_comaddpg, CoMADDPGSettings, base,
                                                   "actor")
    assert not set(VALIDATION_COLUMNS) & set(last_log[0])
    skip = ("wall_s", *VALIDATION_COLUMNS)
    for row, same in zip(log, last_log, strict=True):
        assert {k: v for k, v in row.items() if k not in skip} \
            == {k: v for k, v in same.items() if k != "wall_s"}
    assert all(np.isfinite(r[c]) for r in log for c in VALIDATION_COLUMNS)
    kept = kept_row(log)
    assert validation_key(kept) == max(validation_key(r) for r in log)
    assert best.settings["keep_network"] == "best"
    prefix, _ = train_comaddpg(CoMADDPGSettings(**{**base, "episodes": int(kept["episode"]),
                                                   "keep_network": "last"}))
    for a, b in zip(best.actor.parameters(), prefix.actor.parameters(), strict=True):
        assert torch.equal(a, b)
    settings = CoMADDPGSettings(**base)
    again = greedy_validation(settings, validation_env(settings, settings.env_config()),
                              best.actor)
    assert again == {c: kept[c] for c in VALIDATION_COLUMNS}  # the kept actor's run, repeated
    assert kept_note(log).startswith(f"kept the actor of the best greedy validation run, after "
                                     f"episode {kept['episode']:.0f}: "
                                     f"{kept['validation_collisions']:.0f} collision events")
    assert kept_note(last_log) is None


def test_validation_runs_each_environment_as_alone(tiny_run) -> None:
    """An environment's validation run does not depend on how many run beside it (the actor is
    called once per environment, as in an evaluation), so the first N of a larger validation
    are the validation on N environments; the measures sum and average over environments."""
    settings = CoMADDPGSettings(**{**TINY.to_dict(), "densities": (900.0, 2100.0),
                                   "rows": 1, "cols": 1, "validation_steps": 300})
    actor = tiny_run[0].actor
    two = validation_runs(settings, validation_env(settings, settings.env_config(), 2), actor)
    five = validation_runs(settings, validation_env(settings, settings.env_config(), 5), actor)
    for field in ("collisions", "reward_sum", "transitions", "velocity", "throughput"):
        np.testing.assert_array_equal(getattr(five, field)[:2], getattr(two, field))
    assert five.measures(2) == two.measures()
    assert (five.transitions > 0).all() and (five.throughput > 0).all()
    assert two.measures()["validation_velocity"] == pytest.approx(two.velocity.mean())
    assert two.measures()["validation_reward"] == pytest.approx(
        two.reward_sum.sum() / two.transitions.sum())
    # the environments cycle the densities: the third runs the first density on the next seed
    env = validation_env(settings, settings.env_config(), 3)
    assert list(env.densities) == [900.0, 2100.0, 900.0]
    for bad in (0, 4097):
        with pytest.raises(ConfigError, match="validation_envs"):
            CoMADDPGSettings(validation_envs=bad).check()


def test_validation_counts_once_the_noise_has_decayed_and_at_the_end() -> None:
    # 150 steps per episode, decay over 0.5 x 600: step 300, episode 3's first, has noise_end
    _, log = train_comaddpg(CoMADDPGSettings(**{**TINY.to_dict(), "episodes": 4,
                                                "noise_decay_fraction": 0.5}))
    assert [np.isfinite(r["validation_reward"]) for r in log] == [False, False, True, True]
    assert log[2]["noise_sd"] == pytest.approx(TINY.noise_end) != log[1]["noise_sd"]
    _, log = train_comaddpg(CoMADDPGSettings(**{**TINY.to_dict(), "episodes": 2,
                                                "noise_decay_fraction": 1.0}))
    assert [np.isfinite(r["validation_reward"]) for r in log] == [False, True]  # the last


def test_checkpoints_round_trip_and_refuse_foreign_files(tiny_run, tmp_path) -> None:
    policy = tiny_run[0]
    path = policy.save(tmp_path / "c.pt")
    loaded = CoMADDPGPolicy.load(path)
    obs = np.random.default_rng(0).uniform(-1, 1, (9, TINY.k, 3)).astype(np.float32)
    np.testing.assert_array_equal(loaded(obs), policy(obs))
    assert loaded.settings == TINY.to_dict() and loaded.checkpoint == str(path)
    with pytest.raises(CheckpointError, match="holds the 'signal_dqn' policy, but a 'comaddpg'"):
        CoMADDPGPolicy.load(shipped_pa_dqn_path(1, 1))
    bad = tmp_path / "bad.pt"
    bad.write_bytes(path.read_bytes()[:200])
    with pytest.raises(CheckpointError, match=r"bad\.pt"):
        CoMADDPGPolicy.load(bad)
    with pytest.raises(ValueError, match=r"obs: expected shape \(n, 8, 3\)"):
        policy(obs[:, :4])


def test_evaluation_batch_equals_single_runs_and_checks_its_policy(tiny_run) -> None:
    policy = tiny_run[0]
    batch = evaluate_batch("comaddpg", 1, 1, [600, 1800], 200, [0, 1],
                           policies={"vehicle": policy}, progress=False)
    single = evaluate_scheme("comaddpg", 1, 1, 1800, 200, 1, policies={"vehicle": policy},
                             progress=False)
    keys = ["avg_travel_velocity_mps", "throughput", "collisions", "backlog", "mean_speed_mps"]
    assert [single[k] for k in keys] == [batch[3][k] for k in keys]
    assert single["coordinator_actions"] == "policy" and single["scheme"] == "comaddpg"
    assert single["control"] == "unsignalized" and "batch_size" not in single
    with pytest.raises(ConfigError, match=r"scheme 'comaddpg' needs policies\['vehicle'\]"):
        evaluate_scheme("comaddpg", 1, 1, 900, 10, 0, progress=False)
    with pytest.raises(ConfigError, match="'vehicle' is used by scheme"):
        evaluate_scheme("E", 1, 1, 900, 10, 0, policies={"vehicle": policy}, progress=False)
    with pytest.raises(ConfigError, match="model: scheme 'comaddpg' needs model='paper'"):
        evaluate_scheme("comaddpg", 1, 1, 900, 10, 0, policies={"vehicle": policy},
                        progress=False, model="released")
    with pytest.raises(ConfigError, match="step_hook: not available"):
        evaluate_scheme("comaddpg", 1, 1, 900, 10, 0, policies={"vehicle": policy},
                        progress=False, step_hook=lambda env, t: None)


def test_command_line(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert cli.main(["train-comaddpg", "--out", str(out), "--episodes", "1", "--batch", "1",
                     "--episode-steps", "120", "--warmup", "32", "--minibatch", "16",
                     "--densities", "900", "--save-validated", "--validation-steps", "200",
                     "--validation-envs", "1"]) == 0
    captured = capsys.readouterr()
    assert captured.out.strip() == str(out / "comaddpg.pt")
    assert "episode 1/1: reward/vehicle-step" in captured.err
    assert "mivecc: kept the actor of the best greedy validation run, after episode 1" \
        in captured.err
    assert (out / "train_log.csv").read_text().startswith("episode,noise_sd,")
    assert (out / "learning_curve.png").stat().st_size > 10_000
    validated = CoMADDPGPolicy.load(out / "validated" / "episode_01.pt")  # the only validation
    for a, b in zip(validated.actor.parameters(), CoMADDPGPolicy.load(out / "comaddpg.pt")
                    .actor.parameters(), strict=True):
        assert torch.equal(a, b)
    assert cli.main(["evaluate", "--scheme", "comaddpg", "--vehicle-checkpoint",
                     str(out / "comaddpg.pt"), "--steps", "100", "--json",
                     "--no-progress"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["scheme"] == "comaddpg"
    assert result["vehicle_checkpoint"].endswith("comaddpg.pt")
    for argv, message in (
        (["evaluate", "--scheme", "comaddpg", "--no-pretrained"],
         "scheme comaddpg needs a vehicle policy; give --vehicle-checkpoint"),
        (["evaluate", "--scheme", "comaddpg", "--vehicle-checkpoint", str(tmp_path / "no.pt")],
         "--vehicle-checkpoint: "),
        (["evaluate", "--scheme", "comaddpg", "--vehicle-checkpoint",
          str(shipped_pa_dqn_path(1, 1))], "holds the 'signal_dqn' policy"),
        (["train-comaddpg", "--out", str(out), "--gamma", "2"], "gamma: must be a number"),
        (["train-comaddpg", "--out", str(out), "--critic-view", "all"],
         "argument --critic-view: invalid choice: 'all'"),
        (["train-comaddpg", "--out", str(out), "--validation-envs", "0"],
         "validation_envs: must be"),
        (["train-comaddpg", "--out", str(out), "--keep-network", "last", "--save-validated"],
         "--save-validated: needs --keep-network best"),
    ):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1


def test_shipped_policy_is_the_documented_run() -> None:
    shipped = CoMADDPGPolicy.load(SHIPPED_PATH)
    # `mivecc train-comaddpg --out DIR --keep-network last`; trained before critic_view
    # existed (its critic read the references' actions: the default) and before keep_network
    # validation_steps and validation_envs (read as the last actor, validated for an episode's
    # steps on one environment per density)
    assert {"critic_view": "actions", **shipped.settings} == CoMADDPGSettings(
        keep_network="last", validation_steps=1000, validation_envs=7).to_dict()
    assert shipped.k == CoMADDPGSettings().k
    assert isinstance(shipped.actor, VehicleActor)


def test_shipped_policy_reproduces_its_committed_comparison_run() -> None:
    import csv
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "docs/results/comparison/comparison.csv"
    with open(path, newline="", encoding="utf-8") as fh:
        (row,) = [r for r in csv.DictReader(fh) if r["scheme"] == "comaddpg"
                  and r["rows"] == "1" and float(r["density"]) == 1500 and r["seed"] == "1"]
    run = evaluate_scheme("comaddpg", 1, 1, 1500, 3000, 1, progress=False,
                          policies={"vehicle": CoMADDPGPolicy.load(SHIPPED_PATH)})
    for key in ("avg_travel_velocity_mps", "collisions", "throughput", "backlog"):
        assert run[key] == float(row[key]), key
    assert run["collisions"] == 0.0  # documented: collision-free on 1x1


def test_training_commands_keep_stdout_for_the_checkpoint_path(tmp_path) -> None:
    # TorchRL logs a line when the replay buffer is made; it goes to stderr, not before the path
    import subprocess
    import sys

    out = tmp_path / "run"
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from mivecc_agents import cli; "
         "sys.exit(cli.main(sys.argv[1:]))", "train-comaddpg", "--out", str(out),
         "--episodes", "1", "--batch", "1", "--episode-steps", "150", "--warmup", "16",
         "--minibatch", "8", "--densities", "1500", "--validation-steps", "150"],
        capture_output=True, text=True,
        timeout=300, check=True)
    assert done.stdout == f"{out / 'comaddpg.pt'}\n"
    assert "episode 1/1" in done.stderr and "Initialized LazyTensorStorage" in done.stderr
